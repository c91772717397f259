"""One module per paper result; each returns pandas tables and plain values, never prints.

- :mod:`.transducer_projections` — notebook 01: the digital model and synthetic biplane frames.
"""

"""One module per paper result; each returns pandas tables and plain values and never prints.

Its ``record_*`` functions write a report section through the ``SectionWriter`` a notebook
passes in; this layer sits below ``reporting`` and does not import it. Nothing is imported here:
a notebook imports its module (``from histostudy.study import segmentation as study``).

- :mod:`.transducer_projections` — notebook 01: the digital and physical models, a synthetic biplane pair, render timing (§II-A eq. 1-2, §II-B.1, §II-B.2).
- :mod:`.segmentation` — notebook 02: the U-Net on held-out hybrid frames, Table I, ANOVA and Tukey HSD (§II-B.2, §II-E.1, §III); its shipped-weights and held-out-frame helpers serve notebook 03 too.
- :mod:`.orientation_regression` — notebook 03: VGG19 azimuth and elevation against the true pose, MAE, Pearson, Moore-Penrose fit; the conic initialiser beside it (§II-B.4 eq. 4, §II-E.2, §III).
- :mod:`.stats` — notebooks 02 and 03: segmentation metrics, one-way ANOVA, Tukey HSD, angle statistics (§II-E.1, §II-E.2).
- :mod:`.pose_estimation` — notebook 04: the pose-estimation experiments and Table II (§II-B.3, §II-D, §II-E.3, §III).
- :mod:`.projector_comparison` — notebook 04, beyond the paper: the pose pipeline on frames of RTK's independent projector (§II-B.2).
- :mod:`.targeting` — notebook 05: calibration, targeting and treatment of the phantom (§II-C, §II-D, §II-E.4, §III).
"""

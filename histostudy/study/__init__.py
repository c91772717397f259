"""The study: one folder per notebook (``projections`` 01, ``segmentation`` 02, ``orientation`` 03,
``pose`` 04, ``targeting`` 05, ``your_data`` 06, ``budget`` 07), each giving its notebook's
``<Section>Config``, ``prepare``, part functions and ``record`` (docs/architecture.md, "Notebook sections"),
over the shared :mod:`.section`, :mod:`.stats` and :mod:`.held_out`. It returns tables, figures and
values and never prints; :class:`LabErrorModel` is imported on first use.
"""

__all__ = ["LabErrorModel"]


def __getattr__(name: str):
    if name == "LabErrorModel":
        from .budget import LabErrorModel

        return LabErrorModel
    raise AttributeError(f"module 'histostudy.study' has no attribute {name!r}")

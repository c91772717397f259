"""The lab's own data and equipment (§II-A to §II-D on real hardware): the workflow a lab runs on its
C-arm's files, its CBCT and its robot — pose from frames, hand-eye calibration, a target in the
CBCT and the planned (or executed) robot moves (``workflow``) — the frames streamed live from the
C-arm over DICOM (``receiver``, biplane pairing in ``pairing``), and a small lab-like dataset the
project generates to stand in for a lab's files (``dataset``).
"""

# every public name of the modules above, as each module's __all__ declares it
__all__: list[str] = list(dict.fromkeys([]))

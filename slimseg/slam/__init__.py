"""Trajectory-level evaluation (``slimseg slam-eval``, ``slimseg slam vocab``).

- :mod:`.vocab`: DBoW2 text vocabulary of ORB descriptors (build, validate);
- :mod:`.settings`: ORB-SLAM3 RGB-D settings file from a sequence's camera;
- :mod:`.engines`: ORB-SLAM3 (``pyorbslam3``, optional) and dense RGB odometry (OpenCV);
- :mod:`.conditions`: what each condition feeds an engine (raw, masked, replaced frames);
- :mod:`.metrics`: ATE/RPE with evo (optional), the standing-still floor;
- :mod:`.evaluate`, :mod:`.session`: runs per condition, medians; :mod:`.report`: tables, plot;
- :mod:`.trajectory`: TUM trajectory rows (published numbers: :mod:`slimseg.eval.paper`).

``pyorbslam3`` and ``evo`` are GPL-3.0 and live in the ``[slam]`` extra: nothing here imports
them at module level.
"""

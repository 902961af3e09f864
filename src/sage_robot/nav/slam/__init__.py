"""2D graph SLAM: scan-to-map matching, pose graph with loop closures, occupancy mapping.

Pure numpy/scipy algorithms (:mod:`engine`, :mod:`matcher`, :mod:`posegraph`,
:mod:`occupancy`), CARMEN log reading (:mod:`carmen`), the Kümmerle relation metric
(:mod:`relations`), save/load (:mod:`store`) and the bus node (:mod:`node`).
"""

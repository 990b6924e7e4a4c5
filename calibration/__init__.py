"""Calibration and plotting tools for the pedestrian models (paper Table I, docs/RESULTS.md).

Run from the repository root as modules: ``python -m calibration.calibrate`` and
``python -m calibration.plot_trajectories``; both drive ``target/release/sim-server eval-peds``.
"""

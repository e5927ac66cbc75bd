"""Closed-loop verification of an exported controller in its task's MuJoCo C twin (`gsa verify`).

Modules by concern: system (the controller, its task and the state coordinates), simulate (batched closed-loop
rollouts on mujoco.batch), linearize (fixed points, the closed loop's Jacobian and eigenvalues), roa (region of
attraction by the task's one convergence rule, Lyapunov sublevel set, LQR beside it), falsify (cross-entropy search
for low-return episodes, replayable counterexamples judged by their neighbours), switching (which pieces the closed
loop uses and how often it changes them), certify (a certified region of attraction of a stable fixed point,
--certify), analysis (all of them for one controller, each timed), report (verify.json, report.md, figures). NumPy,
SciPy and MuJoCo only, no JAX; certify's semidefinite program needs cvxpy and Clarabel (the optional extra verify).
"""

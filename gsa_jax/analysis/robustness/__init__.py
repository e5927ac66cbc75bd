"""Exported controllers under shifted physics, observations and actions, and paired pushes: evaluation,
statistics, fair comparisons and figures."""

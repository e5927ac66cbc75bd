"""The orchestration layer: what trains many runs as jobs above running and analysis (the answer loop, its
sweeps as subprocesses, their progress line)."""

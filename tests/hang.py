"""Wall-clock limits of the suite: hang guards, never a measure of speed.

A test that waits on a subprocess, a worker pool or a server bounds its wait so that a hang fails
that test instead of stalling the whole run; each bound is far above the slowest time the wait
has taken on a loaded 2-core machine with an empty Warp kernel cache, so a slow or busy machine
never fails a test. (A benchmark's smoke run took 42 s on this 2-core machine with a cold cache
and another process on the second core, and over 300 s on one with more work running.) Speed is
measured side by side in ``benchmarks/``, not here.
"""

#: A subprocess that runs a script, an example or a benchmark's smoke profile to the end.
HANG_S = 1800.0
#: Worker processes (a local pool, a Dask cluster, a spawned run) starting and reporting in.
START_S = 300.0

"""Shared set-up of the torch tests: one intra-op thread.

The networks of the reference-like agents are tiny; torch's default of one thread
per core makes each small operation wait for the other threads, and on a machine
whose cores are busy (cargo building, other test binaries) that made the checks
about ten times slower (BESO's check: 9.4 s against 1.0 s on one thread).
Results do not depend on it: the checks compare within a tolerance.
"""

import torch

torch.set_num_threads(1)

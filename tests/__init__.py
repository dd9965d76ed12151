"""fabkit's tests. The commands they run in-process get the BLAS threads ``fabkit``'s
entry gives a command (fabkit/entry.py, ``BLAS_THREADS``): set here, before numpy and
scipy load their OpenBLAS, whose idle threads would spin beside the other test worker."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

"""fabkit's tests. The commands they run in-process get the BLAS threads ``fabkit``'s
entry gives a command (:func:`fabkit.entry.one_blas_thread`; that module imports nothing
but built-in ones): set here, before numpy and scipy load their OpenBLAS, whose idle
threads would spin beside the other test worker."""

from fabkit.entry import one_blas_thread

one_blas_thread()

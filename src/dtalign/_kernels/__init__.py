"""Pure Numba kernels: valid, C-contiguous float64 input assumed, never validated."""

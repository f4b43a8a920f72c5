"""What the kernels offer a `NetworkConfig`, named without JAX (a config is read and checked before JAX is
imported): the convolutions' implementations (`IMPLS`, `conv`), the compute dtypes (`DTYPES`, `precision`)
and the kernel size of every convolution (`KERNEL`)."""

KERNEL = 3
IMPLS = ("matmul", "im2col", "xla")
DTYPES = ("float32", "bfloat16")
"""`NetworkConfig.dtype` values: the input dtype of the network's matrix products and convolutions."""

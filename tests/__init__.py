"""The test suite of cosim.

The frame digests (``tests/frame_digests.py``) hold bit for bit only for one choice of numerical
kernels: OpenBLAS picks its kernels by the CPU (Haswell, SkylakeX, Zen, ...) and NumPy its SIMD
loops (AVX2, AVX-512), and their last bits differ, which an estimator's adaptive step control or a
quantized CAN signal turns into other frames. Every process of a test session (pytest, the node
processes it starts, ``python -m tests.frame_digests``) therefore runs with OpenBLAS's Haswell
kernels and NumPy's dispatch up to AVX2, which every x86-64 machine since 2013 has. This must be set
before NumPy is first imported, which is why it lives here, in the package every test module and
the conftest import first.
"""

import os
import sys

if "numpy" in sys.modules:  # pragma: no cover - a plugin imported NumPy before the tests
    import warnings

    warnings.warn("NumPy was imported before tests/__init__.py: its kernels are not pinned", stacklevel=1)
os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")
os.environ.setdefault("NPY_DISABLE_CPU_FEATURES", "X86_V4 AVX512_ICL AVX512_SPR")

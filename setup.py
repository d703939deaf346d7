"""The one compiled part of cfstack: estimator/_eskf_kernels.c (everything else is in pyproject.toml).

Optional: where it cannot be built (no C compiler), pip installs cfstack without it and the estimator runs
its Python twin (estimator/eskf_kernels.py), which gives the same results, slower.
-ffp-contract=off: no fused multiply-add, so the C gives the Python twin's bits on every CPU.
"""

from setuptools import Extension, setup

setup(ext_modules=[Extension("estimator._eskf_kernels", ["estimator/_eskf_kernels.c"],
                             extra_compile_args=["-ffp-contract=off"], optional=True)])

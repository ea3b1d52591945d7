import glob
import os

import setuptools

# The compiled fast path (octoprint_kincomp/engines/kernel.py). Optional: without a C compiler the
# plugin installs all the same and runs on its pure-Python paths. No fused multiply-add:
# the kernel's arithmetic must round exactly as Python's does.
kernel = setuptools.Extension(
    "octoprint_kincomp.engines._kernel",
    sorted(glob.glob("octoprint_kincomp/engines/csrc/*.c")),
    depends=glob.glob("octoprint_kincomp/engines/csrc/*.h"),
    optional=True,
    # (no builtins for the libm functions: the kernel must call the very functions Python's
    # math module calls, not a merged sincos or a compile-time constant)
    extra_compile_args=[]
    if os.name == "nt"
    else [
        "-ffp-contract=off",
        "-fno-builtin-sin",
        "-fno-builtin-cos",
        "-fno-builtin-atan2",
        "-fno-builtin-acos",
    ],
    libraries=[] if os.name == "nt" else ["m"],
)

setuptools.setup(license="AGPL-3.0-or-later", ext_modules=[kernel])

"""The one compiled part: swarm.proto._wire, the wire codec of the flat message kinds (docs/runtime.md).
Optional: where no C compiler is found the install goes on and the same codec runs as generated Python."""
from setuptools import Extension, setup

setup(ext_modules=[Extension("swarm.proto._wire", ["swarm/proto/_wire.c"], optional=True,
                             extra_compile_args=["-O2", "-std=c99", "-Wall", "-Wno-missing-field-initializers"])])

"""The compiled parts of a robot process's control period (docs/runtime.md, "A robot's control period"):
swarm.proto._wire, a robot's loops over its messages (three C files sharing _wire.h), and swarm.core._law, the law transcribed from
swarm/core/law.py; and world._referee, the world's look at every pair of robots each tick (world/referee.py). All optional: where
no C compiler is found the install goes on and the same Python runs."""
from setuptools import Extension, setup

FLAGS = ["-O2", "-std=c99", "-Wall", "-Wno-missing-field-initializers",
         "-ffp-contract=off", "-fno-fast-math"]  # the law's floats as Python computes them: no fused multiply-add

WIRE = ["swarm/proto/_wire.c", "swarm/proto/_wire_states.c", "swarm/proto/_wire_window.c"]

setup(ext_modules=[Extension("swarm.proto._wire", WIRE, depends=["swarm/proto/_wire.h"], optional=True,
                             extra_compile_args=FLAGS),
                   Extension("swarm.core._law", ["swarm/core/_law.c"], optional=True, extra_compile_args=FLAGS,
                             libraries=["m"]),
                   Extension("world._referee", ["world/_referee.c"], optional=True, extra_compile_args=FLAGS,
                             libraries=["m"])])

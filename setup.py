"""Build the shipped models' generated sources (generated/<model>/) into gagen.shipped."""

from pathlib import Path

import numpy
from Cython.Build import cythonize
from setuptools import Extension, setup

HERE = Path(__file__).parent


def shipped_extensions():
    extensions = []
    for folder in sorted((HERE / "generated").glob("*/")):
        pyx = sorted(folder.glob("gagen_*.pyx"))
        if len(pyx) != 1:
            continue
        module = pyx[0].stem
        # the model's C files (gagen.codegen.MODEL_C_FILES), not Cython's output
        sources = [pyx[0]] + sorted(f for f in folder.glob("*.c")
                                    if not f.name.startswith("gagen_"))
        extensions.append(Extension(
            f"gagen.shipped.{module}",
            [str(s.relative_to(HERE)) for s in sources],
            include_dirs=[str(folder.relative_to(HERE)), numpy.get_include()],
            define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
            extra_compile_args=["-O3"],
        ))
    return extensions


setup(ext_modules=cythonize(shipped_extensions(), language_level=3, quiet=True))

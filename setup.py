"""gagen's compiled runtime (gagen.runtime._native, Cython) and the shipped models' generated
sources (generated/<model>/, plain C) as gagen.shipped.<module>."""

import re
from pathlib import Path

import numpy
from Cython.Build import cythonize
from setuptools import Extension, setup

HERE = Path(__file__).parent
TEMPLATES_C = HERE / "src" / "gagen" / "codegen" / "templates" / "c"


def relative(path: Path) -> str:
    return str(path.relative_to(HERE))


def runtime_extension() -> Extension:
    """The runtime every model's module is used through (it reads their gagen_api.h tables)."""
    return Extension("gagen.runtime._native", [relative(HERE / "src/gagen/runtime/_native.pyx")],
                     include_dirs=[relative(TEMPLATES_C), numpy.get_include()],
                     define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
                     extra_compile_args=["-O3"])


def constraint_terms_extension() -> Extension:
    """The constrained dynamics' derivatives in C (gagen.runtime.constraint_derivatives calls
    it; without it, the same in NumPy); it calls the models' kernels through gagen_api.h."""
    return Extension("gagen.runtime._constraint_terms",
                     [relative(HERE / "src/gagen/runtime/_constraint_terms.pyx")],
                     include_dirs=[relative(TEMPLATES_C), numpy.get_include()],
                     depends=[relative(TEMPLATES_C / "gagen_constraint_derivatives.h")],
                     define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
                     extra_compile_args=["-O3"])


def shipped_extensions() -> list[Extension]:
    """A model's module from its committed sources: its C files, module.c naming the module."""
    extensions = []
    for folder in sorted((HERE / "generated").glob("*/")):
        init = folder / "module.c"
        found = re.search(r"PyInit_(gagen_\w+)\(", init.read_text()) if init.exists() else None
        if found is None:
            continue
        # the model's C files (gagen.codegen.render's MODEL_C_FILES and module.c)
        # (not constrained_derivatives.c, which needs the derivative module: builder._c_files)
        sources = sorted(f for f in folder.glob("*.c") if not f.name.startswith("gagen_")
                         and f.name != "constrained_derivatives.c")
        extensions.append(Extension(
            f"gagen.shipped.{found.group(1)}", [relative(s) for s in sources],
            include_dirs=[relative(folder)], extra_compile_args=["-O3"]))
    return extensions


setup(ext_modules=[*cythonize([runtime_extension(), constraint_terms_extension()],
                             language_level=3, quiet=True),
                   *shipped_extensions()])

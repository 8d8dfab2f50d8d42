"""Builds the compiled extensions, voro3d._cgal and voro3d._fitkernel; the rest is in pyproject.toml."""
from pybind11.setup_helpers import ParallelCompile, Pybind11Extension, build_ext
from setuptools import setup

# An extension's sources compile at once (one per CPU; VORO3D_BUILD_JOBS=N sets how many), and the two
# extensions at once too (build_ext's parallel below): 45 s on two cores instead of 85 s in a row, of
# which CGAL's Delaunay file alone takes 40 s.
ParallelCompile("VORO3D_BUILD_JOBS").install()

setup(
    ext_modules=[
        Pybind11Extension(
            "voro3d._cgal",
            ["src/voro3d_cgal.cpp", "src/voro3d_clean.cpp"],
            depends=["src/voro3d_checks.h", "src/clean/types.h", "src/clean/state.h", "src/clean/bounds.h",
                     "src/clean/rules.h"],
            cxx_std=17,
            define_macros=[("NDEBUG", None), ("CGAL_DISABLE_ROUNDING_MATH_CHECK", None)],
            extra_compile_args=["-O3", "-pthread"],
            extra_link_args=["-pthread"],
            libraries=["gmp", "mpfr"],
        ),
        Pybind11Extension(
            "voro3d._fitkernel",
            ["src/voro3d_fitkernel.cpp", "src/voro3d_winding.cpp", "src/voro3d_filter.cpp",
             "src/voro3d_imls.cpp"],
            depends=["src/voro3d_parallel.h", "src/voro3d_checks.h"],
            cxx_std=17,
            extra_compile_args=["-O3", "-pthread"],
            extra_link_args=["-pthread"],
        ),
    ],
    cmdclass={"build_ext": build_ext},
    options={"build_ext": {"parallel": True}},  # the two extensions at once too
)

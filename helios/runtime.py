"""Process-wide numeric runtime settings: native thread pools and the CPU code paths.

Threads. On the 2-vCPU machines this project targets, multi-threaded BLAS and torch kernels are erratic
and often far slower than one thread (measured: a (72000, 3) @ (3, 3) matmul takes 23 ms with
OpenBLAS on 2 threads and 0.5 ms on 1; torch shows the same). Parallelism comes from processes
(trial workers, the render worker) instead, so every entry point pins native pools explicitly.

CPU code paths. NumPy, OpenBLAS, torch (ATen, MKL, oneDNN) and OpenCV pick SIMD kernels at run
time by what the CPU offers, and the AVX-512 kernels round differently from the AVX2 ones in the
last bits (NumPy's exp/log/sin, BLAS reductions). An episode is a long chain of decisions on
such numbers: on 20 train episodes, the AVX2 and the AVX-512 paths of this machine already gave
two records apart in the 13th digit (an object's resting place), and over 200 episodes outcomes
differ. So that a run folder reproduces on any x86-64 machine with AVX2, every entry point
(``python -m tools``, its worker processes, the test suite) pins the libraries to the x86-64-v3
level (AVX2 + FMA) before they load: :func:`pin_cpu_dispatch`. ``HELIOS_CPU=native`` turns it off
(each library then takes its fastest path, and numbers may differ from machine to machine).
"""

from __future__ import annotations

import os
import sys

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def configure_threads(n: int = 1) -> None:
    """Limit BLAS/OpenMP/torch thread pools to ``n`` in this process (and its children).

    Environment variables cover libraries not yet loaded and child processes; threadpoolctl and
    ``torch.set_num_threads`` cover the ones already loaded.
    """
    if n < 1:
        raise ValueError(f"thread count must be >= 1, got {n}")
    for var in _THREAD_VARS:
        os.environ[var] = str(n)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(n)
    except ImportError:  # pragma: no cover - threadpoolctl is a pinned dependency
        pass
    import sys

    import cv2     # OpenCV's pool (erosions, distance transforms) would use every core

    cv2.setNumThreads(n)
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(n)


# ------------------------------------------------------------------------------------------------
# CPU code paths (see the module docstring)
# ------------------------------------------------------------------------------------------------
PORTABLE_LEVEL = "x86-64-v3"
"""The CPU level results are pinned to: AVX2 and FMA (Intel since Haswell, AMD since Zen)."""
CPU_ENV_VAR = "HELIOS_CPU"
"""``native`` turns the pin off; unset or ``x86-64-v3`` pins."""
_NUMPY_AVX512_TARGETS = {True: ("X86_V4", "AVX512_ICL", "AVX512_SPR"),           # NumPy >= 2.4
                         False: ("AVX512F", "AVX512_SKX", "AVX512_ICL", "AVX512_SPR")}
_OPENCV_AVX512 = "AVX512-SKX"
"""OpenCV's one AVX-512 dispatch target (its wheels build AVX2 and AVX512_SKX kernels); OpenCV
prints a warning for every listed feature the CPU lacks, so only this one, where the CPU has it."""
_SKX_FLAGS = {"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}
_LEVEL_VARS = {"OPENBLAS_CORETYPE": "Haswell", "ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2",
               "ONEDNN_MAX_CPU_ISA": "AVX2"}
_PINNED_MODULES = ("numpy", "torch", "cv2", "scipy")
PIN_VARS = (*_LEVEL_VARS, "NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE")
"""Every variable the pin may set."""


def _proc_cpuinfo() -> str | None:
    """The text of ``/proc/cpuinfo``; None where there is none (not Linux)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            return fh.read()
    except OSError:
        return None


def _cpuinfo_line(cpuinfo: str, name: str) -> str | None:
    """The value (after the colon) of the first ``name`` line of ``cpuinfo``; None without one."""
    for line in cpuinfo.splitlines():
        if line.startswith(name):
            return line.partition(":")[2]
    return None


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """The CPU's feature flags from ``/proc/cpuinfo`` (empty where there is none: not Linux)."""
    text = _proc_cpuinfo() if cpuinfo is None else cpuinfo
    return set((_cpuinfo_line(text, "flags") or "").split()) if text is not None else set()


def cpu_model(cpuinfo: str | None = None) -> str:
    """The CPU's model name from ``/proc/cpuinfo`` (``platform.processor()`` where there is none).

    The pinned code path does not make every record machine-independent (README, "One CPU code
    path": a 200-episode re-run on an AMD EPYC moved a few episodes; the same code on an Intel Xeon
    moved one reference record by 0.4 ms of simulated time), so exact comparisons name the
    machine they were made on."""
    text = _proc_cpuinfo() if cpuinfo is None else cpuinfo
    if text is None:
        import platform

        return platform.processor() or "unknown"
    value = _cpuinfo_line(text, "model name")
    return " ".join(value.split()) if value is not None else "unknown"


def _numpy_at_least_2_4() -> bool:
    from importlib.metadata import PackageNotFoundError, version

    try:
        major, minor = (int(p) for p in version("numpy").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return True
    return (major, minor) >= (2, 4)


def check_cpu_choice(environ) -> str:
    """``HELIOS_CPU`` as given in ``environ``: ``x86-64-v3`` (also when unset) or ``native``;
    ValueError naming the variable otherwise."""
    choice = environ.get(CPU_ENV_VAR, PORTABLE_LEVEL).strip().lower()
    if choice not in (PORTABLE_LEVEL, "native"):
        raise ValueError(f"{CPU_ENV_VAR} must be {PORTABLE_LEVEL} or native (or unset), "
                         f"got {environ[CPU_ENV_VAR][:60]!r}")
    return choice


def cpu_pin_settings(flags: set[str], environ: dict[str, str], machine: str,
                     numpy_2_4: bool = True) -> tuple[dict[str, str], str]:
    """The environment variables that pin the libraries to ``PORTABLE_LEVEL`` on a CPU with
    ``flags``, and a one-line description of the result (recorded with each run).

    Pure, for tests: nothing is set here. Nothing is pinned where ``HELIOS_CPU=native``, off
    x86-64, or on a CPU without AVX2 and FMA (the level's kernels would not run there: such
    machines keep their own paths and may not reproduce others' numbers bit for bit). NumPy's
    AVX-512 targets are listed only where the CPU has AVX-512 (otherwise there is nothing to
    turn off) and never together with ``NPY_ENABLE_CPU_FEATURES`` (NumPy refuses both); targets
    already disabled in the environment are kept."""
    if check_cpu_choice(environ) == "native":
        return {}, f"native ({CPU_ENV_VAR}=native)"
    if machine.lower() not in ("x86_64", "amd64"):
        return {}, f"native (no pin for {machine} CPUs)"
    if not {"avx2", "fma"} <= flags:
        return {}, "native (this CPU lacks AVX2 or FMA; results may differ from x86-64-v3 machines)"
    out = dict(_LEVEL_VARS)
    if "avx512f" in flags:
        if environ.get("NPY_ENABLE_CPU_FEATURES"):
            return {}, "native (NPY_ENABLE_CPU_FEATURES is set, which NumPy refuses with a pin)"
        have = environ.get("NPY_DISABLE_CPU_FEATURES", "").replace(",", " ").split()
        out["NPY_DISABLE_CPU_FEATURES"] = " ".join(have + [t for t in _NUMPY_AVX512_TARGETS[numpy_2_4] if t not in have])
        have = [h.strip() for h in environ.get("OPENCV_CPU_DISABLE", "").replace(";", ",").split(",") if h.strip()]
        if _SKX_FLAGS <= flags and _OPENCV_AVX512 not in have:
            have.append(_OPENCV_AVX512)
        if have:
            out["OPENCV_CPU_DISABLE"] = ",".join(have)
    return out, PORTABLE_LEVEL


def _settings_here() -> tuple[dict[str, str], str]:
    """:func:`cpu_pin_settings` for this machine and this process's environment."""
    import platform

    return cpu_pin_settings(cpu_flags(), dict(os.environ), platform.machine(), _numpy_at_least_2_4())


def pin_cpu_dispatch() -> str:
    """Pin NumPy, OpenBLAS, torch and OpenCV to ``PORTABLE_LEVEL`` in this process and its
    children (see :func:`cpu_pin_settings`); returns the description. It must run before any of
    them is imported, since they read the environment when they load: where one already is
    (and the pin is not already in the environment, as in a worker started by a pinned parent),
    nothing is changed and the description says so, so the process never runs half pinned."""
    settings, what = _settings_here()
    missing = {k: v for k, v in settings.items() if os.environ.get(k) != v}
    loaded = [m for m in _PINNED_MODULES if m in sys.modules]
    if missing and loaded:
        return f"native ({', '.join(loaded)} imported before the pin)"
    os.environ.update(settings)
    return what


def cpu_dispatch() -> dict:
    """Which code paths this process runs (for run provenance): the pin's description, and where
    loaded NumPy's highest active dispatch target, torch's capability and OpenCV's feature line.
    Torch is not imported for it (1-2 s): a process that has not loaded torch yet (``tools trials``
    before its workers start) records no torch entry; the pin's ``ATEN_CPU_CAPABILITY`` holds."""
    settings, what = _settings_here()
    if any(os.environ.get(k) != v for k, v in settings.items()):
        what = "native (not pinned in this process)"
    out: dict = {"pin": what}
    if "numpy" in sys.modules:
        try:
            from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
        except ImportError:  # pragma: no cover - NumPy < 2
            from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
        active = [t for t in __cpu_dispatch__ if __cpu_features__.get(t)]
        out["numpy"] = active[-1] if active else "baseline"
    if "torch" in sys.modules:
        import torch

        out["torch"] = torch.backends.cpu.get_cpu_capability()
    if "cv2" in sys.modules:
        import cv2

        out["opencv"] = cv2.getCPUFeaturesLine()
    return out

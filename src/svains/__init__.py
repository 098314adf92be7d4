"""svains: tightly-coupled stereo vision-aided inertial navigation (Asadi & Bottasso 2014).

Conventions (quaternions Hamilton scalar-first, frames in names, int64 ns timestamps) are in
``docs/conventions.md``.
"""

__version__ = "0.1.0"

__all__ = ["InitialState", "NavState", "Navigator", "RunConfig", "RunResult", "__version__"]

_LAZY = {
    "InitialState": "svains.navigation.init",
    "Navigator": "svains.navigation.navigator",
    "NavState": "svains.navigation.outputs",
    "RunResult": "svains.navigation.outputs",
    "RunConfig": "svains.navigation.options",
}


def __getattr__(name: str) -> object:
    # Lazy, so ``import svains`` stays cheap (no numpy/scipy until the estimator is used).
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'svains' has no attribute {name!r}")

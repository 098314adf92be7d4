"""svains: tightly-coupled stereo vision-aided inertial navigation (Asadi & Bottasso 2014).

Conventions (quaternions Hamilton scalar-first, frames in names, int64 ns timestamps) are in
``docs/conventions.md``.
"""

__version__ = "0.1.0"

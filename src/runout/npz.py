"""Reading .npz files from elsewhere without running the code a pickle may carry.

`np.load(allow_pickle=True)` executes whatever a pickled object array asks for. The GNS
layouts need pickle only to store object arrays of numeric arrays, so members are read
here as follows: numeric arrays with `allow_pickle=False`; object arrays with an unpickler
that may build numpy arrays, dtypes and scalars and nothing else (no other class, no
function call), after which the caller checks that every element is numeric. Anything else
(a raw pickle, another global, a corrupt member) is refused with one sentence.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np

from runout.errors import InputError
from runout.reading import file_to_read

try:  # numpy >= 2
    from numpy._core import multiarray as _multiarray, numeric as _numeric
except ImportError:  # numpy 1.x
    from numpy.core import multiarray as _multiarray, numeric as _numeric

# The only globals a pickled object array of numeric arrays refers to (numpy 1.x and 2.x names).
_ALLOWED = {
    (module, name): obj
    for modules, name, obj in (
        (("numpy.core.multiarray", "numpy._core.multiarray"), "_reconstruct", _multiarray._reconstruct),
        (("numpy.core.multiarray", "numpy._core.multiarray"), "scalar", _multiarray.scalar),
        (("numpy.core.numeric", "numpy._core.numeric"), "_frombuffer", _numeric._frombuffer),
        (("numpy",), "ndarray", np.ndarray),
        (("numpy",), "dtype", np.dtype),
    )
    for module in modules
}
NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats


class _Refused(Exception):
    """A pickle asked for something other than numpy array reconstruction."""


class _ArrayUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) in _ALLOWED:
            return _ALLOWED[(module, name)]
        raise _Refused(f"{module}.{name}")


class SafeNpz:
    """The members of an .npz archive, read one at a time: `files`, `archive[key]`.

    Raises InputError when the file is not a zip archive or a member is corrupt, holds a
    pickle that asks for anything but numpy arrays, or holds a non-numeric array."""

    def __init__(self, path: str | Path):
        self.path = file_to_read(path, "npz file")
        if not zipfile.is_zipfile(self.path):
            kind = "a single .npy array" if _is_npy(self.path) else "not a zip archive"
            raise InputError(f"{self.path}: not a readable npz file ({kind}); nothing in it was read.")
        try:
            self._zip = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError) as exc:
            raise InputError(f"{self.path}: not a readable npz file ({exc}).") from None
        self.files = [n[: -len(".npy")] for n in self._zip.namelist() if n.endswith(".npy")]

    def __enter__(self) -> "SafeNpz":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._zip.close()

    def __getitem__(self, key: str) -> np.ndarray:
        try:
            return self._read(key)
        except _Refused as exc:
            raise InputError(
                f"{self.path}: refused to read '{key}' because its pickle asks for '{exc}', "
                "and a GNS file holds only numeric arrays (nothing was run)."
            ) from None
        except (zipfile.BadZipFile, OSError, ValueError, EOFError, pickle.UnpicklingError, KeyError) as exc:
            raise InputError(f"{self.path}: member '{key}' is corrupt or not an array ({exc}).") from None

    def text(self, key: str) -> str:
        """A member holding one string (numpy unicode, no pickle), e.g. the device of a part file."""
        try:
            with self._zip.open(f"{key}.npy") as f:
                array = np.lib.format.read_array(f, allow_pickle=False)
        except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError) as exc:
            raise InputError(f"{self.path}: member '{key}' is corrupt or not text ({exc}).") from None
        if array.dtype.kind != "U" or array.ndim != 0:
            raise InputError(f"{self.path}: member '{key}' has dtype {array.dtype} and shape {array.shape}; expected one string.")
        return str(array)

    def _read(self, key: str) -> np.ndarray:
        name = f"{key}.npy"
        with self._zip.open(name) as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                _, _, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                _, _, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise ValueError(f".npy format version {version} is not supported")
            if dtype.hasobject:
                array = _ArrayUnpickler(f).load()
                if not isinstance(array, np.ndarray):
                    raise ValueError(f"the pickle holds a {type(array).__name__}, not an array")
                return array
        with self._zip.open(name) as f:
            array = np.lib.format.read_array(f, allow_pickle=False)
        if array.dtype.kind not in NUMERIC_KINDS:
            raise ValueError(f"dtype {array.dtype} is not numeric")
        return array


def _is_npy(path: Path) -> bool:
    with open(path, "rb") as f:
        return f.read(6) == b"\x93NUMPY"


def read_npy(path: str | Path, what: str) -> np.ndarray:
    """The numeric array of a .npy file, read without pickle; InputError naming the file when
    it is missing, unreadable, an object array or not numeric."""
    path = file_to_read(path, what)
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npy array of numbers ({exc}); nothing in it was run.") from None
    if not isinstance(array, np.ndarray) or array.dtype.kind not in NUMERIC_KINDS:
        kind = f"dtype {array.dtype}" if isinstance(array, np.ndarray) else type(array).__name__
        raise InputError(f"{path}: holds {kind}; expected a .npy array of numbers.")
    return array


def numeric(value, what: str, source: Path) -> np.ndarray:
    """`value` (an array or Python number from an object array) as a numeric ndarray, or
    InputError naming what it is."""
    if isinstance(value, (bool, int, float, np.number, np.bool_)):
        return np.asarray(value)
    if isinstance(value, np.ndarray) and value.dtype.kind in NUMERIC_KINDS:
        return value
    kind = f"an array of dtype {value.dtype}" if isinstance(value, np.ndarray) else f"a {type(value).__name__}"
    raise InputError(f"{source}: {what} is {kind}; expected a numeric array.")

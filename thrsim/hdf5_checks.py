"""Checked reads of HDF5 datasets from files a user hands thrsim (meshes, case files, packs, sessions).

A dataset is read only after its kind (a dataset, not a group), dtype, shape and size are checked:
a small file can declare a dataset of many GiB (unwritten chunks take no space), a string where
numbers belong would fail deep inside NumPy, and int64 indices cast to int32 would wrap. Each
problem is a :class:`ThrsimInputError` naming the file, the dataset and the value.
"""

from __future__ import annotations

import h5py
import numpy as np

from thrsim.errors import ThrsimInputError

#: the most thrsim reads of one dataset (a default case's largest is 10 MB, a 10-million-tet mesh's tets 160 MB)
MAX_DATASET_BYTES = 1 << 30
INT32_MAX = np.iinfo(np.int32).max
_KIND_NAMES = {"f": "floating-point numbers", "iu": "integers", "u": "unsigned integers", "fiu": "numbers"}


def dataset_at(group: h5py.Group, name: str, source: object) -> h5py.Dataset:
    """``group[name]`` if it is a dataset; else one line naming what is there instead."""
    item = group.get(name)
    where = f"{group.name.rstrip('/')}/{name}"
    if item is None:
        raise ThrsimInputError(f"{source}: missing dataset {where}")
    if not isinstance(item, h5py.Dataset):
        raise ThrsimInputError(f"{source}: {where} is a {type(item).__name__.lower()}, expected a dataset")
    return item


def group_at(parent: h5py.Group, name: str, source: object) -> h5py.Group:
    """``parent[name]`` if it is a group; else one line naming what is there instead."""
    item = parent.get(name)
    where = f"{parent.name.rstrip('/')}/{name}"
    if item is None:
        raise ThrsimInputError(f"{source}: missing group {where}")
    if not isinstance(item, h5py.Group):
        raise ThrsimInputError(f"{source}: {where} is a {type(item).__name__.lower()}, expected a group")
    return item


def check_dataset(item: h5py.Dataset, source: object, kinds: str | None = "fiu", shape: tuple[int | None, ...] | None = None) -> None:
    """Refuse a dataset of another dtype kind (``kinds``: NumPy kind letters; None: any), another
    shape (None: any length on that axis; ``shape`` None: any) or more than :data:`MAX_DATASET_BYTES`."""
    if kinds is not None and item.dtype.kind not in kinds:
        raise ThrsimInputError(f"{source}: {item.name} has dtype {item.dtype}, expected {_KIND_NAMES.get(kinds, kinds)}")
    if shape is not None and (
        item.ndim != len(shape) or any(want is not None and got != want for got, want in zip(item.shape, shape, strict=True))
    ):
        wanted = "(" + ", ".join("n" if n is None else str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ThrsimInputError(f"{source}: {item.name} has shape {item.shape}, expected {wanted}")
    size = int(item.size) * item.dtype.itemsize
    if size > MAX_DATASET_BYTES:
        raise ThrsimInputError(
            f"{source}: {item.name} declares {item.shape} {item.dtype}, {size / 2**30:.1f} GiB; "
            f"thrsim reads at most {MAX_DATASET_BYTES / 2**30:.0f} GiB per dataset"
        )


def read_dataset(
    group: h5py.Group,
    name: str,
    source: object,
    kinds: str = "fiu",
    shape: tuple[int | None, ...] | None = None,
    *,
    finite: bool = True,
    int32: bool = True,
) -> np.ndarray:
    """The whole of ``group[name]`` after :func:`check_dataset`; with ``int32``, integers must fit
    thrsim's index type (never wrapped), with ``finite``, floating-point values must be finite."""
    item = dataset_at(group, name, source)
    check_dataset(item, source, kinds, shape)
    try:
        values = item[()]
    except (OSError, ValueError, TypeError) as error:
        raise ThrsimInputError(f"{source}: {item.name} cannot be read ({' '.join(str(error).split())})") from None
    if int32 and values.dtype.kind in "iu" and values.size and (values.max() > INT32_MAX or values.min() < -INT32_MAX - 1):
        raise ThrsimInputError(f"{source}: {item.name} holds {int(values.max())}, beyond the int32 indices thrsim uses")
    if finite and values.dtype.kind == "f" and not np.isfinite(values).all():
        raise ThrsimInputError(f"{source}: {item.name} holds NaN or infinite values")
    return values

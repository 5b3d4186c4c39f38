"""One table on disk: written and read back exactly (CSV or Parquet), and a flight folder's checksum."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset.record import DatasetError

#: numpy kinds whose values are their bytes (bool, integers, floats, complex, datetimes)
PLAIN_KINDS = "biufcmM"


def plain_columns(df: pd.DataFrame) -> dict:
    """Label -> numpy array of each column whose values are plain numbers (``df[label].to_numpy()``,
    the same array), without building a Series per column: a dataset's writer reads every column
    of every topic of every flight, and ``df[label]`` costs ~40 us where the whole frame's arrays
    cost ~2 us a column. Columns of other dtypes (text, nullable extension types) and frames with
    repeated labels are left out: read them as ``df[label]``."""
    if not df.columns.is_unique:
        return {}
    arrays = getattr(df, "_iter_column_arrays", None)  # pandas' own column iterator (pandas >= 1.3)
    it = arrays() if arrays is not None else (df.iloc[:, j].to_numpy() if isinstance(df.dtypes.iloc[j], np.dtype)
                                              else None for j in range(df.shape[1]))
    return {label: a for label, a in zip(df.columns, it)
            if isinstance(a, np.ndarray) and a.dtype.kind in PLAIN_KINDS}


def write_table(df: pd.DataFrame, path: Path, fmt: str) -> None:
    if fmt == "parquet":
        df.to_parquet(path.with_suffix(".parquet"), index=False, compression="zstd")
    else:
        df.to_csv(path.with_suffix(".csv"), index=False, float_format=None)


def read_table(path: Path, columns: list[str] | None = None) -> pd.DataFrame:
    for suffix in (".parquet", ".csv"):
        p = path.with_suffix(suffix)
        if p.exists():
            if suffix == ".parquet":
                return pd.read_parquet(p, columns=columns)
            df = read_csv_exact(p, columns)
            for c in ("Anomaly_Ids", "Anomaly_Kind"):  # CSV has no empty string: it reads back as NaN
                if c in df.columns:
                    df[c] = df[c].astype(object).where(df[c].notna(), "")
            return df
    raise DatasetError(f"{path}.(parquet|csv): no such table")


def read_csv_exact(path: Path, columns: list[str] | None) -> pd.DataFrame:
    """Floats exactly as written (pandas 3 deprecates ``float_precision``; newer ones drop it)."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            return pd.read_csv(path, usecols=columns, float_precision="round_trip")
    except TypeError:
        return pd.read_csv(path, usecols=columns)


def flight_checksum(root: Path) -> str:
    """A digest of every file of a flight folder (names and bytes, BLAKE2b-128): recorded in the
    manifest when the flight is written, compared when it is read, so a changed byte is caught and
    the dataset fingerprint (which covers the manifest) follows the contents."""
    h = hashlib.blake2b(digest_size=16)
    for f in sorted(p for p in root.rglob("*") if p.is_file()):
        h.update(f.relative_to(root).as_posix().encode() + b"\0")
        h.update(f.read_bytes())
    return "b2:" + h.hexdigest()

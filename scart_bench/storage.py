"""Datasets and run folders at fsspec URLs (``s3://``, ``gs://``, ``az://``, ``file://``, ...).

The readers and writers of this project work on local folders; an object store is reached by
staging, with the guarantees of the local format kept:

- **Reading a dataset** (:func:`fetch_dataset`): the manifest is read first (no manifest: not a
  complete dataset, refused), then every object under the URL is downloaded into a local cache
  folder keyed by the URL and the manifest's digest, which is renamed into place when whole; a
  second read of the same dataset is a cache hit. Dask workers call it themselves, so they need
  the URL and credentials, not a shared disk.
- **Writing a dataset** (:func:`publish_dataset`): written locally (or, by a sharded generation,
  its flights uploaded by the workers), then uploaded with the manifest last; an existing dataset
  being replaced loses its manifest first. A dataset at a URL is therefore complete exactly when
  its manifest exists, as on disk; a failed upload leaves no manifest.
- **Run folders and reports** (:func:`fetch_folder`, :func:`push_folder`): downloaded into a local
  folder, worked on there, uploaded back (the run's flight cache stays local).

Object stores have no locks: two commands writing the same URL at once are not prevented.
Bad URLs, a missing fsspec backend (s3fs, gcsfs, adlfs) and missing credentials raise
:class:`StorageError`, one line naming the URL and what was expected.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import tempfile
from pathlib import Path

from scart_bench.errors import ScartBenchError

_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*://")
#: fsspec backends per scheme, for the "install ..." hint
_BACKENDS = {"s3": "s3fs (pip install 'scart-bench[s3]')", "s3a": "s3fs (pip install 'scart-bench[s3]')",
             "gs": "gcsfs (pip install gcsfs)", "gcs": "gcsfs (pip install gcsfs)",
             "az": "adlfs (pip install adlfs)", "abfs": "adlfs (pip install adlfs)"}
MANIFESTS = ("manifest.parquet", "manifest.csv")


class StorageError(ScartBenchError):
    """A URL cannot be read or written as asked (bad URL, no backend, no credentials, no bucket)."""


def is_url(location: object) -> bool:
    """True for a URL with a scheme other than ``file://`` (a local path otherwise)."""
    return isinstance(location, str) and bool(_SCHEME.match(location)) and not location.startswith("file://")


def local_path(location: str | Path) -> Path:
    """A local path or ``file://`` URL as a Path (not for remote URLs)."""
    s = str(location)
    return Path(s[len("file://"):]) if s.startswith("file://") else Path(s)


def _fs(url: str):
    """(filesystem, path inside it) of ``url``; StorageError when no backend can open it."""
    scheme = url.split("://", 1)[0].lower()
    try:
        import fsspec

        fs, path = fsspec.core.url_to_fs(url)
    except ImportError as exc:
        need = _BACKENDS.get(scheme, f"the fsspec backend of {scheme}://")
        raise StorageError(f"{url}: {scheme}:// URLs need {need} ({exc})") from None
    except (ValueError, TypeError) as exc:
        raise StorageError(f"{url}: not a URL fsspec can open ({exc}); expected e.g. s3://bucket/path") from None
    fs.invalidate_cache()
    return fs, path.rstrip("/")


def _access(url: str, exc: BaseException) -> StorageError:
    what = f"{type(exc).__name__}: {exc}".strip().rstrip(":")
    return StorageError(f"{url}: cannot access it ({what}); expected an existing bucket and credentials that "
                        "can read and write it (for s3://: AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY or ~/.aws, and "
                        "AWS_ENDPOINT_URL for a non-AWS server)")


def _call(url: str, fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except Exception as exc:  # backends raise their own types (botocore, aiohttp): one line naming the URL
        raise _access(url, exc) from None


def has_manifest(url: str) -> str | None:
    """The manifest's name when a complete dataset is at ``url`` (None when there is none)."""
    fs, root = _fs(url)
    for name in MANIFESTS:
        if _call(url, fs.exists, f"{root}/{name}"):
            return name
    return None


def has_objects(url: str) -> bool:
    """True when anything is stored under ``url``."""
    fs, root = _fs(url)
    return bool(_files(fs, root))


def check_writable(url: str) -> None:
    """Refuse (StorageError) a URL this process cannot write: writes and removes a probe object."""
    fs, root = _fs(url)
    probe = f"{root}/.scart-bench-probe-{os.getpid()}"
    _call(url, fs.pipe_file, probe, b"")
    _call(url, fs.rm_file, probe)


def _files(fs, root: str) -> list[str]:
    """Every object under ``root`` as a path relative to it."""
    try:
        found = fs.find(root)
    except FileNotFoundError:
        return []
    return sorted(p[len(root):].lstrip("/") for p in found if p.startswith(root))


def fetch_dataset(url: str, cache_root: str | Path | None = None) -> Path:
    """A local copy of the complete dataset at ``url`` (downloaded once per manifest; see module doc)."""
    from scart_bench.dataset.locks import FolderLock

    fs, root = _fs(url)
    name = has_manifest(url)
    if name is None:
        raise StorageError(f"{url}: no manifest.parquet or manifest.csv there; expected a complete scart-bench "
                           "dataset (one is complete once its manifest is written)")
    manifest = _call(url, fs.cat_file, f"{root}/{name}")
    key = hashlib.sha256(url.encode() + b"\0" + manifest).hexdigest()[:24]
    base = Path(cache_root) if cache_root else default_cache()
    folder = base / "datasets" / key
    with FolderLock(base / "datasets" / f".{key}.lock", str(folder)):
        if (folder / name).exists():
            return folder
        tmp = Path(tempfile.mkdtemp(prefix=f".{key}.", dir=folder.parent))
        try:
            rels = [r for r in _files(fs, root) if r not in MANIFESTS and not r.startswith(".scart-bench-probe")]
            _call(url, fs.get, [f"{root}/{r}" for r in rels], [str(tmp / r) for r in rels])
            (tmp / name).write_bytes(manifest)  # the manifest read first: the copy is the dataset it names
            shutil.rmtree(folder, ignore_errors=True)
            os.replace(tmp, folder)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return folder


def default_cache() -> Path:
    """Where downloaded datasets are kept: ``$SCART_BENCH_CACHE`` or ``~/.cache/scart-bench``."""
    return Path(os.environ.get("SCART_BENCH_CACHE") or Path.home() / ".cache" / "scart-bench")


def clear(url: str) -> None:
    """Remove the dataset at ``url``: its manifest first (it stops being complete), then the rest."""
    fs, root = _fs(url)
    for name in MANIFESTS:
        if _call(url, fs.exists, f"{root}/{name}"):
            _call(url, fs.rm_file, f"{root}/{name}")
    rels = _files(fs, root)
    if rels:
        _call(url, fs.rm, [f"{root}/{r}" for r in rels])


def upload_folder(local: str | Path, url: str, exclude: tuple[str, ...] = ()) -> None:
    """Upload every file under ``local`` to ``url`` (same relative paths), except the top-level
    entries named in ``exclude``."""
    local = Path(local)
    fs, root = _fs(url)
    files = [p for p in sorted(local.rglob("*")) if p.is_file()
             and p.relative_to(local).parts[0] not in exclude]
    if files:
        _call(url, fs.put, [str(p) for p in files], [f"{root}/{p.relative_to(local).as_posix()}" for p in files])


def publish_dataset(local: str | Path, url: str, flights_uploaded: bool = False) -> None:
    """Upload the complete local dataset ``local`` to ``url`` with its manifest last (the caller
    cleared an old dataset there first, see :func:`clear`). ``flights_uploaded``: the flight
    folders are there already (a sharded generation's workers put them)."""
    local = Path(local)
    names = [n for n in MANIFESTS if (local / n).exists()]
    if not names:
        raise StorageError(f"{local}: no manifest; only a complete dataset is uploaded to {url}")
    upload_folder(local, url, exclude=(*MANIFESTS, *(("flights",) if flights_uploaded else ())))
    fs, root = _fs(url)
    _call(url, fs.put_file, str(local / names[0]), f"{root}/{names[0]}")


def fetch_folder(url: str, dest: str | Path) -> bool:
    """Download every object under ``url`` into ``dest``; False when there is nothing there."""
    fs, root = _fs(url)
    rels = _files(fs, root)
    if rels:
        _call(url, fs.get, [f"{root}/{r}" for r in rels], [str(Path(dest) / r) for r in rels])
    return bool(rels)


def push_folder(local: str | Path, url: str, exclude: tuple[str, ...] = ()) -> None:
    """Make ``url`` hold the files of ``local`` (objects no longer there are removed)."""
    fs, root = _fs(url)
    local = Path(local)
    keep = {p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file()
            and p.relative_to(local).parts[0] not in exclude}
    upload_folder(local, url, exclude)
    gone = [f"{root}/{r}" for r in _files(fs, root) if r not in keep and r.split("/")[0] not in exclude]
    if gone:
        _call(url, fs.rm, gone)

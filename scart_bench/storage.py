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

Every object key under a URL becomes a local path through :func:`scart_bench.names.join_inside`
only: a key that would leave its local folder (``..``, ``.`` or empty segments, an absolute key, a
backslash or NUL) refuses the whole URL before anything is written, so whoever can write to a
bucket cannot write outside the cache or staging folder (a ``.pth`` or shell rc file elsewhere).

Local copies live in temp folders owned by their process (:func:`owned_tempdir`: the pid in the
name, a flock on an owner file); those of a process killed with SIGKILL are removed by the next
command's start (:func:`remove_stale_temp`).

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
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from scart_bench.errors import ScartBenchError
from scart_bench.names import join_inside, relative_parts

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
    return bool(_files(fs, root, url))


def check_writable(url: str) -> None:
    """Refuse (StorageError) a URL this process cannot write: writes and removes a probe object."""
    fs, root = _fs(url)
    probe = f"{root}/.scart-bench-probe-{os.getpid()}"
    _call(url, fs.pipe_file, probe, b"")
    _call(url, fs.rm_file, probe)


def _files(fs, root: str, url: str, check: bool = True) -> list[str]:
    """Every object under ``root`` as a key relative to it; with ``check``, IdError naming ``url`` and
    the key for a key that is not a plain relative name (``..``, empty segments, ...: it could leave
    any folder; the fetches check them against their folder instead)."""
    try:
        found = fs.find(root)
    except FileNotFoundError:
        return []
    except Exception as exc:  # backends raise their own types: one line naming the URL
        raise _access(url, exc) from None
    prefix = f"{root}/"
    rels = sorted(p[len(prefix):] for p in found if p.startswith(prefix))
    for rel in rels if check else ():
        relative_parts(rel, f"{url}: object key")
    return rels


def _local_paths(url: str, rels: list[str], folder: Path) -> list[str]:
    """The local path of each key ``rels`` under ``folder``, all checked before anything is written."""
    return [str(join_inside(folder, rel, f"{url}: object key")) for rel in rels]


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
            rels = [r for r in _files(fs, root, url, check=False)
                    if r not in MANIFESTS and not r.startswith(".scart-bench-probe")]
            dests = _local_paths(url, rels, tmp)
            if rels:
                _call(url, fs.get, [f"{root}/{r}" for r in rels], dests)
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
    rels = _files(fs, root, url)
    if rels:
        _call(url, fs.rm, [f"{root}/{r}" for r in rels])


def _local_files(local: Path, exclude: tuple[str, ...]) -> dict[str, Path]:
    """The files under ``local`` by key (relative POSIX path), without the top-level entries ``exclude``."""
    files = {}
    for p in sorted(local.rglob("*")):
        rel = p.relative_to(local)
        if rel.parts[0] not in exclude and p.is_file():
            files[rel.as_posix()] = p
    return files


def snapshot(local: str | Path, exclude: tuple[str, ...] = ()) -> dict[str, tuple[int, int, int]]:
    """What each file under ``local`` is now (size, mtime, inode): :func:`push_folder` uploads only the
    files that changed since the snapshot it is given."""
    out = {}
    for rel, p in _local_files(Path(local), exclude).items():
        try:
            st = p.stat()
        except FileNotFoundError:  # replaced or removed since it was listed: the next snapshot sees it
            continue
        out[rel] = (st.st_size, st.st_mtime_ns, st.st_ino)
    return out


def upload_folder(local: str | Path, url: str, exclude: tuple[str, ...] = (),
                  only: list[str] | None = None) -> None:
    """Upload every file under ``local`` to ``url`` (same relative paths; ``only``: these keys),
    except the top-level entries named in ``exclude``. A local name that is not a plain relative key
    (a backslash, say) is refused: it could not be fetched back (see :func:`fetch_folder`)."""
    local = Path(local)
    fs, root = _fs(url)
    files = _local_files(local, exclude)
    wanted = None if only is None else set(only)
    keys = [k for k in files if wanted is None or k in wanted]
    for key in keys:
        relative_parts(key, f"{local}: file for {url}")
    if keys:
        _call(url, fs.put, [str(files[k]) for k in keys], [f"{root}/{k}" for k in keys])


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


def _same_file(a: Path, b: Path) -> bool:
    import filecmp

    return b.is_file() and filecmp.cmp(a, b, shallow=False)


def update_dataset(local: str | Path, url: str, base: str | Path) -> None:
    """Make the dataset at ``url``, of which ``base`` is the local copy as fetched, hold the dataset
    ``local`` (a command added flights to it), uploading only what changed. New files go up first;
    when files the old manifest names change or go, the old manifest is removed before them and,
    should an upload fail, the old files and manifest are put back, so a failure never costs the
    flights that were already there (a clear and full re-upload could leave them without a manifest)."""
    local, base = Path(local), Path(base)
    names = [n for n in MANIFESTS if (local / n).exists()]
    if not names:
        raise StorageError(f"{local}: no manifest; only a complete dataset is uploaded to {url}")
    fs, root = _fs(url)
    now = {k: p for k, p in _local_files(local, MANIFESTS).items()}
    before = {k: p for k, p in _local_files(base, MANIFESTS).items()}
    new = [k for k in now if k not in before]
    changed = [k for k in now if k in before and not _same_file(now[k], before[k])]
    gone = [k for k in before if k not in now]
    if new:
        upload_folder(local, url, MANIFESTS, only=new)  # not named by the old manifest: harmless until it moves
    if changed or gone:
        old_manifests = [n for n in MANIFESTS if (base / n).is_file()]
        for n in MANIFESTS:
            if _call(url, fs.exists, f"{root}/{n}"):
                _call(url, fs.rm_file, f"{root}/{n}")
        try:
            if changed:
                upload_folder(local, url, MANIFESTS, only=changed)
            if gone:
                _call(url, fs.rm, [f"{root}/{k}" for k in gone])
        except BaseException:
            try:  # the dataset as it was: its files, then its manifest
                upload_folder(base, url, MANIFESTS, only=changed + gone)
                for n in old_manifests:
                    _call(url, fs.put_file, str(base / n), f"{root}/{n}")
            except Exception:  # noqa: S110 - the first error is the one to report
                pass
            raise
    for n in MANIFESTS:  # the other manifest format, if the dataset changed format
        if n != names[0] and _call(url, fs.exists, f"{root}/{n}"):
            _call(url, fs.rm_file, f"{root}/{n}")
    _call(url, fs.put_file, str(local / names[0]), f"{root}/{names[0]}")


def fetch_folder(url: str, dest: str | Path) -> bool:
    """Download every object under ``url`` into ``dest``; False when there is nothing there. Every key
    is checked first (:func:`scart_bench.names.join_inside`): a hostile one refuses the whole URL."""
    fs, root = _fs(url)
    rels = _files(fs, root, url, check=False)
    dests = _local_paths(url, rels, Path(dest))
    if rels:
        _call(url, fs.get, [f"{root}/{r}" for r in rels], dests)
    return bool(rels)


def push_folder(local: str | Path, url: str, exclude: tuple[str, ...] = (),
                since: dict[str, tuple[int, int, int]] | None = None,
                last: tuple[str, ...] = ()) -> dict[str, tuple[int, int, int]]:
    """Make ``url`` hold the files of ``local`` (objects no longer there are removed); with ``since``
    (the :func:`snapshot` of what ``url`` holds already) only new and changed files are uploaded.
    Files named in ``last`` (a folder's commit markers, such as a job's ``status.json``) are uploaded
    after every other file, so a kill mid-upload never leaves a marker whose files (or their
    checksums) are not there yet. Returns the snapshot of what was pushed, for the next call."""
    fs, root = _fs(url)
    local = Path(local)
    now = snapshot(local, exclude)
    changed = [k for k, v in now.items() if since is None or since.get(k) != v]
    markers = [k for k in changed if k.rsplit("/", 1)[-1] in last]
    for batch in ([k for k in changed if k not in markers], markers):
        if batch:
            upload_folder(local, url, exclude, only=batch)
    gone = [f"{root}/{r}" for r in _files(fs, root, url) if r not in now and r.split("/")[0] not in exclude]
    if gone:
        _call(url, fs.rm, gone)
    return now


# -- temp folders owned by this process ------------------------------------------------------------

#: a temp folder made by :func:`owned_tempdir`: scart-<what>-<pid>-<random>, holding the owner file
_OWNED = re.compile(r"scart-[a-z]+-(\d+)-[^-]+")
_OWNER = ".owner"  # beside the folder's content: flock-held by the owning process while it lives


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # another user's, or cannot tell: alive
    return True


def _owner_locked(path: Path) -> bool:
    """True when a live process holds the flock on ``path`` (False without fcntl)."""
    try:
        import fcntl
    except ImportError:
        return False
    try:
        with open(path, "a") as fh:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    return False


def remove_stale_temp(tmpdir: str | Path | None = None) -> list[Path]:
    """Remove the temp folders of :func:`owned_tempdir` (``scart-<what>-<pid>-*``, such as the
    staging folders of URL commands) whose process is gone (killed -9: no ``finally`` ran), and
    return them. Stale means: the pid is not running, and the owner file exists and is not locked
    (the kernel drops a dead process's flock, so a reused pid, or one of another pid namespace
    sharing the temp folder, cannot make a live folder look stale). Other users' folders are left."""
    removed: list[Path] = []
    root = Path(tmpdir or tempfile.gettempdir())
    try:
        candidates = [p for p in root.iterdir() if _OWNED.fullmatch(p.name)]
    except OSError:
        return removed
    for folder in candidates:
        pid = int(_OWNED.fullmatch(folder.name).group(1))
        try:
            if (pid == os.getpid() or _pid_alive(pid) or folder.is_symlink() or not folder.is_dir()
                    or folder.stat().st_uid != os.getuid() or not (folder / _OWNER).is_file()):
                continue
        except OSError:
            continue
        if _owner_locked(folder / _OWNER):
            continue
        shutil.rmtree(folder, ignore_errors=True)
        if not folder.exists():
            removed.append(folder)
    return removed


def claim_tempdir(prefix: str = "scart-stage-"):
    """A new temp folder ``<prefix><pid>-<random>`` (``prefix``: ``scart-<what>-``) and its owner
    file, open and flock-held by this process: (folder, owner). Release both with
    :func:`release_tempdir`; a folder left by a killed process is removed by the next command's start
    (:func:`remove_stale_temp`). For a folder that outlives one block (a job's worker folder);
    :func:`owned_tempdir` is the context manager."""
    if not re.fullmatch(r"scart-[a-z]+-", prefix):
        raise ValueError(f"owned_tempdir prefix {prefix!r}: expected scart-<lowercase letters>-")
    remove_stale_temp()
    tmp = Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-"))
    owner = None
    try:
        owner = open(tmp / _OWNER, "w")  # noqa: SIM115 - held (locked) while the folder is in use
        try:
            import fcntl

            fcntl.flock(owner.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except ImportError:
            pass
        owner.write(f"scart-bench pid {os.getpid()}\n")
        owner.flush()
    except BaseException:
        if owner is not None:
            owner.close()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp, owner


def release_tempdir(folder: Path, owner) -> None:
    """Close the owner file of a :func:`claim_tempdir` folder and remove the folder."""
    try:
        owner.close()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def owned_tempdir(prefix: str = "scart-stage-") -> Iterator[Path]:
    """A new temp folder ``<prefix><pid>-<random>`` (``prefix``: ``scart-<what>-``) owned by this
    process (a flock on its owner file), removed on exit; one left by a killed process is removed by
    the next command's start (:func:`remove_stale_temp`). Put the content in a subfolder: the owner
    file sits at the top."""
    tmp, owner = claim_tempdir(prefix)
    try:
        yield tmp
    finally:
        release_tempdir(tmp, owner)


#: prefix of the local staging folders of URL commands, in the temp folder: scart-stage-<pid>-<random>
STAGE_PREFIX = "scart-stage-"


def stage_name(url: str, default: str) -> str:
    """The local copy's folder name: the URL's last segment when it is a plain id (a run's name), else
    ``default`` (``s3://b/..`` or ``s3://b/x%00`` must not name a folder outside the staging folder)."""
    from scart_bench.names import IdError, check_id

    try:
        return check_id(url.rsplit("/", 1)[-1], "URL name")
    except IdError:
        return default


@contextmanager
def staged_dataset(location: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """A local folder for the dataset at ``location`` that a command creates or adds to: itself, or
    for an fsspec URL a local copy of the dataset there (if any), published back with its manifest
    last once the command succeeded (see :func:`publish_dataset`); after a failure the URL is untouched.
    Objects without a manifest (a half-uploaded dataset) are refused, or with ``overwrite`` replaced
    by the new dataset when it is published."""
    from scart_bench.dataset import is_dataset

    if not is_url(location):
        remove_stale_temp()
        yield local_path(location)
        return
    url = str(location).rstrip("/")
    check_writable(url)
    with owned_tempdir(STAGE_PREFIX) as tmp:
        local = tmp / stage_name(url, "dataset")
        base = None
        if has_manifest(url):
            base = fetch_dataset(url)
            shutil.copytree(base, local)
        elif has_objects(url) and not overwrite:
            raise StorageError(f"{url}: holds objects but no manifest (not a complete scart-bench dataset); "
                               "choose a new prefix, or pass --overwrite to replace them")
        yield local
        if is_dataset(local):
            if base is not None and (base / (has_manifest(url) or "")).is_file():
                update_dataset(local, url, base)  # only what changed; the old dataset kept on failure
            else:
                clear(url)
                publish_dataset(local, url)

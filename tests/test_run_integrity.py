"""Every file a run trusts is checked, and a run folder's JSON is data (issue 45).

- checksums: truth.parquet, arming.csv, flights.csv and each job's status.json, scores.npz and
  alarms.npz are recorded in checksums.json when the run writes them; ``score``, ``report`` and a
  rerun refuse a changed one (exit 2, one line naming the file) instead of scoring wrong labels;
- a damaged or hostile config.json / status.json is one line naming the file, never a traceback;
- parameters, burn-in and ``--features`` that could only fail inside a job are refused up front;
- a property test mutates a small real run and checks that every outcome is "works" or "exit 2 with one
  line naming the file", never a traceback and never exit 0 on data that changed.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from run_fixtures import plugin, write_dataset

from scart_bench.benchmark.store import CHECKSUMS_FILE, RunStore, check_config
from scart_bench.cli.main import main
from scart_bench.errors import ReportError, ScartBenchError

ZS = plugin("ZScore")
CHANGED = "changed since the run wrote it"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


@pytest.fixture(scope="module")
def made_run(dataset, tmp_path_factory) -> Path:
    """A small real run (the z-score test detector and statistical with its own alarm rule), made once."""
    run = tmp_path_factory.mktemp("runs") / "run"
    assert main(["run", "--detectors", "zscore_test,statistical", "--plugin", ZS, "--dataset", str(dataset),
                 "--out", str(run), "--threshold", "own"]) == 0
    return run


@pytest.fixture()
def run(made_run, tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(made_run, copy)
    return copy


def one_line(err: str) -> str:
    """The error output, which must be one line and no traceback."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def flip(path: Path, at: float = 0.5) -> None:
    data = bytearray(path.read_bytes())
    i = int(len(data) * at)
    data[i] ^= 0x01
    path.write_bytes(bytes(data))


def commands(run: Path, tmp_path: Path, dataset: Path) -> dict[str, list[str]]:
    return {"score": ["score", str(run)],
            "report": ["report", str(run), "--out", str(tmp_path / "report"), "--no-figures"],
            "resume": ["run", "--detectors", "zscore_test,statistical", "--plugin", ZS, "--dataset", str(dataset),
                       "--out", str(run), "--threshold", "own", "--resume"]}


# -- checksums ------------------------------------------------------------------------------------

def test_a_run_records_the_checksum_of_every_file_it_trusts(made_run):
    record = json.loads((made_run / CHECKSUMS_FILE).read_text())
    assert set(record["files"]) == {"truth.parquet", "arming.csv", "phases.csv", "flights.csv",
                                    *(f"jobs/{d}/{f}" for d in ("zscore_test", "statistical")
                                      for f in ("status.json", "scores.npz")), "jobs/statistical/alarms.npz"}
    assert json.loads((made_run / "config.json").read_text())["checksums"] == CHECKSUMS_FILE
    RunStore(made_run).verify()


@pytest.mark.parametrize("rel", ["truth.parquet", "arming.csv", "flights.csv", "jobs/zscore_test/scores.npz",
                                 "jobs/statistical/alarms.npz", "jobs/statistical/status.json"])
@pytest.mark.parametrize("command", ["score", "report", "resume"])
def test_a_flipped_byte_is_refused_naming_the_file(run, dataset, tmp_path, capsys, rel, command):
    metrics = (run / "metrics.csv").read_bytes()
    flip(run / rel)
    capsys.readouterr()
    assert main(commands(run, tmp_path, dataset)[command]) == 2
    line = one_line(capsys.readouterr().err)
    assert str(run / rel) in line and CHANGED in line
    assert (run / "metrics.csv").read_bytes() == metrics  # nothing rewritten from the damaged file
    assert not (tmp_path / "report" / "leaderboard.md").exists()


def test_a_flipped_timestamp_in_a_valid_table_is_refused(run, capsys):
    df = pd.read_parquet(run / "truth.parquet")
    df.loc[5, "Timestamp"] += 1  # still a valid, increasing Parquet table
    df.to_parquet(run / "truth.parquet", index=False)
    assert main(["score", str(run)]) == 2
    assert "truth.parquet" in one_line(capsys.readouterr().err)


def test_a_flipped_label_is_refused_where_it_used_to_rescore(run, capsys):
    """The issue's case: one label flipped in truth.parquet was scored (exit 0, wrong metrics)."""
    df = pd.read_parquet(run / "truth.parquet")
    df.loc[df["Is_Anomaly"].idxmax(), "Is_Anomaly"] = 0
    df.to_parquet(run / "truth.parquet", index=False)
    assert main(["score", str(run)]) == 2
    line = one_line(capsys.readouterr().err)
    assert "truth.parquet" in line and CHANGED in line


@pytest.mark.parametrize("value", [None, "", 0, "00", "g" * 64])
def test_a_null_empty_or_malformed_checksum_does_not_skip_verification(run, capsys, value):
    record = json.loads((run / CHECKSUMS_FILE).read_text())
    record["files"]["truth.parquet"] = value
    (run / CHECKSUMS_FILE).write_text(json.dumps(record))
    assert main(["score", str(run)]) == 2
    line = one_line(capsys.readouterr().err)
    assert "truth.parquet" in line and "sha256" in line


def test_a_missing_entry_or_record_is_refused(run, capsys):
    record = json.loads((run / CHECKSUMS_FILE).read_text())
    del record["files"]["jobs/zscore_test/scores.npz"]
    (run / CHECKSUMS_FILE).write_text(json.dumps(record))
    assert main(["score", str(run)]) == 2
    assert "scores.npz: no checksum recorded" in one_line(capsys.readouterr().err)
    (run / CHECKSUMS_FILE).unlink()  # config.json says the run records checksums
    assert main(["score", str(run)]) == 2
    assert f"{CHECKSUMS_FILE}: missing" in one_line(capsys.readouterr().err)
    (run / CHECKSUMS_FILE).write_text("[" * 100_000)
    assert main(["score", str(run)]) == 2
    assert CHECKSUMS_FILE in one_line(capsys.readouterr().err)


def test_a_run_folder_without_checksums_still_scores_quietly(run, tmp_path, capsys):
    (run / CHECKSUMS_FILE).unlink()
    config = json.loads((run / "config.json").read_text())
    del config["checksums"]
    (run / "config.json").write_text(json.dumps(config))
    capsys.readouterr()
    assert main(["score", str(run)]) == 0
    assert main(["report", str(run), "--out", str(tmp_path / "rep"), "--no-figures"]) == 0
    assert "checksum" not in capsys.readouterr().err


def test_a_file_repaired_on_purpose_can_be_sealed(run, capsys):
    flip(run / "jobs/zscore_test/scores.npz")
    RunStore(run).seal("jobs/zscore_test/scores.npz")
    assert main(["score", str(run)]) == 3  # checked now, and unreadable: that job becomes an ERROR row
    assert "not a valid scores file" in pd.read_csv(run / "metrics.csv").set_index("detector").loc[
        "zscore_test", "message"]


def test_resume_after_removing_a_damaged_file_writes_it_again(run, dataset, tmp_path, capsys):
    flip(run / "truth.parquet")
    assert main(commands(run, tmp_path, dataset)["resume"]) == 2
    (run / "truth.parquet").unlink()  # what the message advises
    assert main(commands(run, tmp_path, dataset)["resume"]) == 0
    assert main(["score", str(run)]) == 0


# -- config.json and status.json are data ---------------------------------------------------------

HOSTILE_JSON = ["[" * 100_000, "{not json", "\xff\xfe", "[]", "42", '"text"', "null"]


def _write_hostile(path: Path, text: str) -> None:
    path.write_bytes(b"\xff\xfe" if text == "\xff\xfe" else text.encode("utf-8"))


def test_a_broken_config_json_is_one_line_naming_it(run, tmp_path, capsys):
    """100,000 nested '[' was a RecursionError traceback; the rest are kept from before."""
    for text in HOSTILE_JSON:
        _write_hostile(run / "config.json", text)
        for args in (["score", str(run)], ["report", str(run), "--out", str(tmp_path / "rep"), "--no-figures"]):
            assert main(args) == 2, text[:20]
            assert str(run / "config.json") in one_line(capsys.readouterr().err)


@pytest.mark.parametrize("text", HOSTILE_JSON)
def test_a_broken_status_json_is_one_line_naming_it(run, tmp_path, capsys, text):
    name = "jobs/zscore_test/status.json"
    _write_hostile(run / name, text)
    RunStore(run).seal(name)  # past the checksum, to the reader
    for args in (["score", str(run)], ["report", str(run), "--out", str(tmp_path / "rep"), "--no-figures"]):
        assert main(args) == 2
        assert str(run / name) in one_line(capsys.readouterr().err)


CONFIG_FIELDS = [("identity", "x"), ("identity", None), ("identity.protocol", [1]), ("identity.protocol.burn_in_s", "x"),
                 ("identity.protocol.burn_in_s", 1e12), ("identity.protocol.flight_rule", None),
                 ("identity.protocol.flight_rule.alpha", 7), ("detectors", "zscore_test"), ("detectors", [1]),
                 ("jobs", []), ("jobs.zscore_test", 3), ("executor", "local"), ("executor.jobs", "two"),
                 ("executor.jobs", 0), ("dataset", "ds"), ("dataset.flights", []), ("dataset.flights.train", -1),
                 ("train_dataset", "x"), ("name", 5), ("timeout_s", "soon"), ("protocol", 3)]


def set_field(obj: dict, dotted: str, value) -> None:
    *parents, last = dotted.split(".")
    for p in parents:
        obj = obj[p]
    obj[last] = value


@pytest.mark.parametrize(("field", "value"), CONFIG_FIELDS)
def test_a_wrong_typed_config_field_is_named(run, tmp_path, capsys, field, value):
    config = json.loads((run / "config.json").read_text())
    set_field(config, field, value)
    (run / "config.json").write_text(json.dumps(config))
    for args in (["score", str(run)], ["report", str(run), "--out", str(tmp_path / "rep"), "--no-figures"]):
        assert main(args) == 2
        line = one_line(capsys.readouterr().err)
        assert "config.json" in line and field.split(".")[0] in line


STATUS_FIELDS = [("status", "MAYBE"), ("status", None), ("rows_scored", "many"), ("rows_scored", -1),
                 ("fit_seconds", "x"), ("score_seconds", [1]), ("message", {"a": 1}), ("n_train_flights", 1.5)]


@pytest.mark.parametrize(("field", "value"), STATUS_FIELDS)
def test_a_wrong_typed_status_field_is_named(run, capsys, field, value):
    path = run / "jobs/zscore_test/status.json"
    status = json.loads(path.read_text())
    status[field] = value
    path.write_text(json.dumps(status))
    assert main(["score", str(run)]) == 2
    assert CHANGED in one_line(capsys.readouterr().err)  # a run with checksums: the checksum first
    RunStore(run).seal("jobs/zscore_test/status.json")  # past it: the field itself is named
    assert main(["score", str(run)]) == 2
    line = one_line(capsys.readouterr().err)
    assert str(path) in line and field in line


def test_the_reference_page_reads_its_json_bounded(tmp_path):
    from scart_bench.reports.reference import wall_s

    (tmp_path / "wall_s.json").write_text("[" * 100_000)
    with pytest.raises(ScartBenchError, match="wall_s.json"):
        wall_s(tmp_path)
    (tmp_path / "wall_s.json").write_text('{"wall_s": "long"}')
    with pytest.raises(ReportError, match="wall_s.json: wall_s"):
        wall_s(tmp_path)
    (tmp_path / "wall_s.json").write_text('{"wall_s": 12.5}')
    assert wall_s(tmp_path) == 12.5


def test_check_config_accepts_the_old_fixture():
    fixture = Path(__file__).parent / "data" / "run_made_before_the_rooms" / "config.json"
    check_config(json.loads(fixture.read_text()), fixture)


# -- up-front validation --------------------------------------------------------------------------

@pytest.mark.parametrize(("args", "named"), [
    (["--detectors", "statistical", "--param", f"statistical.window={10**12}"], "window"),
    (["--detectors", "statistical", "--param", "statistical.window=5000"], "statistical.window=5000"),
    (["--detectors", "tsbitmaps", "--param", "tsbitmaps.level_size=40"], "level_size"),
    (["--detectors", "zscore_test", "--plugin", ZS, "--burn-in", "1e12"], "--burn-in"),
    (["--detectors", "zscore_test", "--plugin", ZS, "--burn-in", "25"], "--burn-in 25"),
    (["--detectors", "zscore_test", "--plugin", ZS, "--features", "no_such_topic.*"], "--features no_such_topic.*"),
    (["--detectors", "zscore_test", "--plugin", ZS, "--exclude", "*"], "--exclude *"),
])
def test_parameters_that_could_only_fail_in_the_job_are_refused_up_front(dataset, tmp_path, capsys, args, named):
    out = tmp_path / "run"
    assert main(["run", *args, "--dataset", str(dataset), "--out", str(out)]) == 2
    line = one_line(capsys.readouterr().err)
    assert named in line and "expected" in line
    assert not (out / "jobs").exists()


# -- property test: random damage to a real run ---------------------------------------------------

STATUS_FILES = ["jobs/zscore_test/status.json", "jobs/statistical/status.json"]
BYTE_FILES = ["truth.parquet", "arming.csv", "flights.csv", "jobs/zscore_test/scores.npz",
              "jobs/statistical/scores.npz", "jobs/statistical/alarms.npz"]


def _json_mutation():
    """(file, how, field, value) of a random damage to config.json or a job's status.json."""
    values = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=True),
                       st.text(max_size=20), st.just([]), st.just({}), st.just("[" * 200),
                       st.lists(st.integers(), max_size=3))
    config_fields = st.sampled_from(["identity", "identity.protocol", "identity.protocol.burn_in_s",
                                     "identity.protocol.alarm_rule", "identity.protocol.row_rule", "identity.seed",
                                     "detectors", "jobs", "executor", "executor.jobs", "dataset",
                                     "dataset.flights", "name", "seed", "timeout_s", "train_dataset", "protocol"])
    status_fields = st.sampled_from(["status", "message", "rows_scored", "fit_seconds", "score_seconds",
                                     "n_train_flights", "n_scored_flights", "wall_seconds", "finished"])
    config = st.tuples(st.just("config.json"), st.sampled_from(["set", "delete"]), config_fields, values)
    status = st.tuples(st.sampled_from(STATUS_FILES),
                       st.sampled_from(["set", "delete"]), status_fields, values)
    whole = st.tuples(st.sampled_from(["config.json", "jobs/zscore_test/status.json"]), st.just("replace"),
                      st.just(""), st.sampled_from(range(len(HOSTILE_JSON))))  # an index: a short repr
    return st.one_of(config, status, whole)


def _apply_json(run: Path, mutation) -> None:
    name, how, field, value = mutation
    path = run / name
    if how == "replace":
        path.write_bytes(HOSTILE_JSON[value].encode("utf-8", "replace"))
        return
    try:
        data = json.loads(path.read_text())
    except (ValueError, RecursionError):  # replaced by an earlier mutation: nothing to edit
        return
    if not isinstance(data, dict):
        return
    *parents, last = field.split(".")
    obj = data
    for p in parents:
        if not isinstance(obj, dict) or not isinstance(obj.get(p), dict):
            return
        obj = obj[p]
    if how == "delete":
        obj.pop(last, None)
    else:
        obj[last] = value
    path.write_text(json.dumps(data))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(json_damage=st.lists(_json_mutation(), max_size=2),
       byte_damage=st.lists(st.tuples(st.sampled_from(BYTE_FILES), st.floats(0, 0.999)), max_size=2),
       sealed=st.booleans(), old_folder=st.booleans(), command=st.sampled_from(["score", "report"]))
def test_random_damage_to_a_run_is_refused_in_one_line_or_harmless(made_run, tmp_path_factory, json_damage,
                                                                  byte_damage, sealed, old_folder, command):
    """Whatever is damaged, ``score`` and ``report`` work or exit 2 with one line naming the damaged file;
    a run with checksums never exits 0 after a byte it trusts changed. ``sealed``: the changed job files'
    checksums recorded again (to reach the readers behind the checksums); ``old_folder``: the run as one
    made before checksums."""
    import contextlib
    import io

    tmp = tmp_path_factory.mktemp("prop")
    run = tmp / "run"
    shutil.copytree(made_run, run)
    store = RunStore(run)
    if old_folder:
        (run / CHECKSUMS_FILE).unlink()
        config = json.loads((run / "config.json").read_text())
        del config["checksums"]
        (run / "config.json").write_text(json.dumps(config))
    for mutation in json_damage:
        _apply_json(run, mutation)
    for rel, at in byte_damage:
        flip(run / rel, at)
    touched = {rel for rel in {*BYTE_FILES, *STATUS_FILES, "config.json"}
               if (run / rel).read_bytes() != (made_run / rel).read_bytes()}
    if sealed and not old_folder:
        for rel in touched - {"config.json"}:
            store.seal(rel)
    args = (["score", str(run)] if command == "score"
            else ["report", str(run), "--out", str(tmp / "rep"), "--no-figures"])
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(args)
    text = err.getvalue()
    assert "Traceback" not in text
    if rc == 2:
        line = one_line(text)
        assert any(str(run / name) in line for name in touched | {CHECKSUMS_FILE}), (line, touched)
    else:
        assert rc in (0, 3), (rc, text)  # 3: a job's saved scores unusable, named in its row
        # a run that records checksums never scores a trusted file that changed since the run wrote it
        assert old_folder or sealed or not touched - {"config.json"}, (touched, rc)

"""Every output file written whole (issue 43): one helper (eha.outputs) writes a temporary
file beside the destination, flushes it and renames it; a failure (a full disk) leaves the
old file as it was and no temporary, and its one line names the file."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from eha.outputs import OutputError, atomic_path, write_atomic, write_json


def test_written_whole_with_the_mode_of_any_file_and_no_temporary(tmp_path):
    path = write_json(tmp_path / "a" / "x.json", {"k": [1, 2]})
    assert json.loads(path.read_text()) == {"k": [1, 2]}
    assert [p.name for p in path.parent.iterdir()] == ["x.json"]
    with atomic_path(tmp_path / "f.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path
        tmp.write_bytes(b"png")
    assert (tmp_path / "f.png").read_bytes() == b"png"


def test_an_error_inside_the_block_leaves_the_old_file(tmp_path):
    (tmp_path / "x.json").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "x.json") as tmp:
            tmp.write_text("half")
            raise RuntimeError("stop")
    assert (tmp_path / "x.json").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]


def test_a_full_disk_leaves_the_old_file_and_names_it(tmp_path):
    """The file size limit (RLIMIT_FSIZE) stands in for a full disk: the write fails at
    4 kB, as the audit's full disk did with rul.json."""
    (tmp_path / "rul.json").write_text('{"old": true}')
    code = textwrap.dedent(f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        from eha.outputs import OutputError, write_json
        try:
            write_json({str(tmp_path / 'rul.json')!r}, {{"x": "y" * 100000}})
        except OutputError as exc:
            print(exc.exit_code, exc)
            sys.exit(0)
        sys.exit(3)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"1 {tmp_path / 'rul.json'}: could not be written (File "
                                  "too large)")
    assert (tmp_path / "rul.json").read_text() == '{"old": true}'
    assert [p.name for p in tmp_path.iterdir()] == ["rul.json"]


def test_the_cli_json_of_a_command_is_written_by_the_helper(tmp_path, monkeypatch):
    """`--json` goes through eha.outputs: a failure there is one line naming the file."""
    from helpers import error_line, invoke_eha

    import eha.outputs as outputs

    def broken(path, data):
        raise OutputError(f"{path}: could not be written (No space left on device); the "
                          "file is left as it was")

    monkeypatch.setattr(outputs, "write_atomic", broken)
    out = tmp_path / "limits.json"
    proc = invoke_eha("limits", "--fault", "FDJ", "--require", "lag(mixed) > 0.02", "--lo",
                      "200", "--hi", "20000", "--tol", "0.4", "--t-end", "0.3", "--json", out)
    line = error_line(proc, 1)
    assert str(out) in line and "No space left on device" in line
    assert not out.exists()


def test_no_output_is_written_with_write_text_or_a_bare_open():
    """The library's outputs go through eha.outputs (the helpers that write traces and tables
    of eha.campaigns, and the caches written beside them, have their own atomic writes)."""
    root = Path(__file__).resolve().parents[1] / "eha"
    found = []
    for path in sorted(root.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        for i, line in enumerate(text.splitlines(), 1):
            bare = (".write_text(" in line or ".savefig(path" in line
                    or ('open(' in line and '"w"' in line and "atomic_path" not in line))
            if bare and "tmp" not in line and path.name not in ("outputs.py", "docgen.py"):
                found.append(f"{path.relative_to(root)}:{i}")
    assert found == [], found

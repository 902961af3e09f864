"""`sage kb ...` end to end in-process: ingest, search --json, list, delete; clear errors."""

from __future__ import annotations

import json

import pytest

from sage_robot.cli.main import main
from sage_robot.kb import service as service_module
from tests.kb.kb_docs import MARKDOWN, TEXT


@pytest.fixture
def data_dir(tmp_path, monkeypatch, embedder):
    monkeypatch.setenv("SAGE_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setattr(service_module, "make_embedder", lambda name: embedder)
    return tmp_path


def test_ingest_search_list_delete(data_dir, capsys):
    folder = data_dir / "docs"
    folder.mkdir()
    (folder / "greenhouse.md").write_bytes(MARKDOWN)
    (folder / "bikes.txt").write_bytes(TEXT)
    (folder / "broken.docx").write_bytes(b"not a zip")
    assert main(["kb", "ingest", str(folder), "--json"]) == 1  # one file failed
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert sorted(x["status"] for x in lines) == ["added", "added", "failed"]
    assert main(["kb", "ingest", str(folder / "greenhouse.md")]) == 0
    assert "unchanged" in capsys.readouterr().out

    assert main(["kb", "search", "where do orchids grow?", "--top-k", "1", "--json"]) == 0
    answer = json.loads(capsys.readouterr().out)
    assert answer["results"][0]["source"].endswith("greenhouse.md")

    assert main(["kb", "list", "--json"]) == 0
    docs = json.loads(capsys.readouterr().out)["documents"]
    assert {d["source"].rsplit("/", 1)[-1] for d in docs} == {"greenhouse.md", "bikes.txt"}  # no corpus:
    # ingest on an empty store does not pull in the shipped documents
    bikes = next(d for d in docs if d["source"].endswith("bikes.txt"))
    assert main(["kb", "delete", str(bikes["id"])]) == 0
    assert main(["kb", "delete", str(bikes["id"])]) == 2
    assert f"no document with id {bikes['id']}" in capsys.readouterr().err


def test_search_on_a_fresh_store_uses_the_shipped_corpus(data_dir, capsys):
    assert main(["kb", "search", "Where is the steam turbine?", "--top-k", "1"]) == 0
    out = capsys.readouterr().out
    assert "Heat and Power Lab" in out
    assert "steam turbine" in out


def test_bad_search_is_one_line_error(data_dir, capsys):
    assert main(["kb", "search", "   "]) == 2
    assert capsys.readouterr().err.strip() == "sage: error: the query is empty"

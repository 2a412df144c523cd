"""The library's event-format table (host/events/event_formats.hpp) against Python's lists and the
docs: vkunroll.EVENT_FORMATS is the binding's table, read_events(format=) and write_events(format=)
take exactly its names, and docs/events.md's format table is its rows (a list that drifts fails here)."""
import pathlib

import numpy as np
import pytest

import vkunroll
from vkunroll import _args as A
from vkunroll import _vkunroll as _vk

ROOT = pathlib.Path(__file__).resolve().parents[2]
DOCS_MARK = "<!-- event-format-table"


def doc_row(f):
    """One row of docs/events.md's format table, as the docs write it."""
    exts = " ".join(f"`{e}`" for e in f.extensions)
    return (f"| `{f.name}` | {f'`{f.alias}`' if f.alias else ''} | {f.what} | {exts} | {f.signature} | "
            f"{'streamed' if f.streamed else 'random access'} | {f.reader} | {'yes' if f.writable else ''} |")


def test_python_names_are_the_tables():
    rows = _vk._event_formats()
    assert [f.name for f in vkunroll.EVENT_FORMATS] == [r["name"] for r in rows]
    names = {n for r in rows for n in (r["name"], r["alias"]) if n}
    assert set(A.EVENT_FORMATS) == names
    assert set(A.WRITABLE_EVENT_FORMATS) == {n for r in rows if r["writable"] for n in (r["name"], r["alias"]) if n}
    assert {"txt", "h5", "evt3", "bag"} <= names  # the table is the library's, not empty


def test_read_events_takes_every_name_and_refuses_others(tmp_path):
    path = tmp_path / "ev.txt"
    path.write_text("# width 8 height 8\n1 2 3 1\n")
    for f in vkunroll.EVENT_FORMATS:
        for name in (f.name, f.alias):
            if not name:
                continue
            if f.name == "txt":
                assert len(vkunroll.read_events(str(path), format=name)) == 1
            else:  # the name is taken; the text file is then refused by that format's reader
                with pytest.raises(ValueError) as e:
                    vkunroll.read_events(str(path), format=name)
                assert not str(e.value).startswith("read_events: format="), e.value
    with pytest.raises(ValueError, match="format"):
        vkunroll.read_events(str(path), format="evt9")


def test_write_events_follows_the_writable_rows(tmp_path):
    ev = np.array([(1, 0, 0, 1), (2, 1, 1, -1)], dtype=vkunroll.EVENT_DTYPE)
    for f in vkunroll.EVENT_FORMATS:
        if f.writable:
            out = tmp_path / f"ev{f.extensions[0]}"
            vkunroll.write_events(str(out), ev, sensor_size=(4, 4))
            assert vkunroll.detect_event_format(str(out)) == f.name
            assert len(vkunroll.read_events(str(out))) == 2
        else:
            with pytest.raises(ValueError):
                vkunroll.write_events(str(tmp_path / "x.bin"), ev, sensor_size=(4, 4), format=f.name)


def test_docs_table_is_the_tables():
    text = (ROOT / "docs" / "events.md").read_text()
    assert DOCS_MARK in text, "docs/events.md lost its generated format table"
    lines = text[text.index(DOCS_MARK):].splitlines()[1:]
    table = []
    for line in lines:
        if not line.startswith("|"):
            break
        table.append(line)
    assert table[2:] == [doc_row(f) for f in vkunroll.EVENT_FORMATS], "\n".join(doc_row(f) for f in vkunroll.EVENT_FORMATS)

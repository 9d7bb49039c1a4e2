"""tools/screenshots.py: its protobuf messages, tab switching, skipping without a browser, and (slow)
real screenshots in the system's Chromium."""

import importlib.util
import struct
import zlib
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    "screenshots", Path(__file__).parents[1] / "tools" / "screenshots.py"
)
shots = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(shots)


def test_protobuf_fields_match_the_encoding_guides_examples():
    # protobuf.dev "Encoding": field 1 = 150 is 08 96 01; field 2 = "testing" is 12 07 74 65 73 74 69 6e 67
    assert shots.field(1, 150) == bytes.fromhex("089601")
    assert shots.field(2, "testing") == bytes.fromhex("120774657374696e67")
    assert shots.field(1, -2) == bytes.fromhex("08feffffffffffffffff01")  # int64 −2: ten bytes
    assert shots.parse(bytes.fromhex("089601120774657374696e67")) == [(1, 150), (2, b"testing")]


def test_set_time_request_names_timeline_time_and_pause():
    ((op, body),) = shots.parse(shots.set_time_request("time", 30_000_000_000))
    assert op == shots.SET_TIME
    fields = dict(shots.parse(body))
    assert shots.parse(fields[2]) == [(1, b"time")]
    assert shots.parse(fields[3]) == [(1, 30_000_000_000)]
    assert fields[5] == 1  # PLAY_STATE_PAUSED


def _blueprint():
    return {
        "/viewport": {"ViewportBlueprint": {"root_container": "root"}},
        "/container/root": {
            "ContainerBlueprint": {
                "container_kind": "Tabs",
                "active_tab": "/container/a",
                "contents": ["/container/a", "view/b"],
            }
        },
        "/container/a": {
            "ContainerBlueprint": {"container_kind": "Horizontal", "display_name": "horizontal"}
        },
        "/view/b": {"ViewBlueprint": {"class_identifier": "TimeSeries", "display_name": "parameters"}},
    }


def test_tabs_are_switched_in_a_copy_of_the_blueprint():
    bp = _blueprint()
    assert shots.tabs(bp) == ("/container/root", {"horizontal": "/container/a", "parameters": "view/b"})
    switched = shots.with_active_tab(bp, "parameters")
    assert switched["/container/root"]["ContainerBlueprint"]["active_tab"] == "view/b"
    assert bp["/container/root"]["ContainerBlueprint"]["active_tab"] == "/container/a"
    with pytest.raises(ValueError, match="tabs are horizontal, parameters"):
        shots.with_active_tab(bp, "fins")


def test_cursor_is_seconds_on_duration_timelines_and_an_index_on_sequences():
    assert shots.timeline_cursor("1.5", 2) == 1_500_000_000 and shots.timeline_cursor("7", 1) == 7


def test_without_a_browser_it_says_so_and_exits_0(tmp_path, monkeypatch, capsys):
    rrd = tmp_path / "x.rrd"
    rrd.write_bytes(b"")
    monkeypatch.delenv("CHROMIUM", raising=False)
    monkeypatch.setattr(shots.shutil, "which", lambda name: None)
    assert shots.main([str(rrd), str(tmp_path / "out")]) == 0
    assert "skipped: no Chromium" in capsys.readouterr().out and not (tmp_path / "out").exists()
    assert shots.main([str(tmp_path / "none.rrd"), str(tmp_path / "out")]) == 2


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and zlib.crc32(data[12:29]) == struct.unpack(">I", data[29:33])[0]
    return struct.unpack(">II", data[16:24])


@pytest.mark.slow
@pytest.mark.skipif(shots.missing() is not None, reason="no Chromium or playwright here")
def test_screenshots_of_a_run_recording(tmp_path, flights):
    from testbed.simulation import recording

    rrd = recording.log_run(tmp_path / "recording.rrd", flights)
    assert (
        shots.main([str(rrd), str(tmp_path / "png"), "--tab", "vertical", "--at", "1", "--size", "800x450"])
        == 0
    )
    (png,) = (tmp_path / "png").iterdir()
    assert png.name == "vertical-1.png" and _png_size(png) == (800, 450)

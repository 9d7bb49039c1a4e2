"""Screenshots of a Rerun recording as its web viewer shows it, without a display.

    python tools/screenshots.py RECORDING.rrd OUT_DIR [--tab NAME ...] [--at VALUE ...]

Serves the recording with `rerun --serve-web` bound to 127.0.0.1 (free ports), opens the web
viewer in a headless Chromium (the system's, driven by the `playwright` package; no browser is
downloaded), and for each tab (default: every tab of the recording's blueprint) and each cursor
position `--at` (seconds on a duration timeline, an index on a sequence one; default: where the
recording opens) writes `OUT_DIR/<tab>[-<at>].png`. The viewer's warnings and the views'
error reports are printed, so a blueprint naming a missing entity shows up here too.

Without Chromium or playwright it says so and exits 0: the screenshots are a convenience.

Tabs are switched and the time cursor moved through the web viewer's own control API
(`WebHandle.viewer_control`), which takes an encoded `ViewerControlRequest` protobuf message
(rerun's `viewer_control.proto`); the few messages used here are encoded below. The field
numbers are those of the viewer shipped with rerun-sdk 0.41, the version the project pins.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM_FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWER_VERSION = "0.41."
# Messages that say nothing about the recording: the page's web fonts and the viewer's examples
# list are not reachable offline, and the web backend ignores some window commands.
BENIGN = (
    "ERR_NAME_NOT_RESOLVED",
    "Failed to fetch",
    "Failed to load examples",
    "Unhandled egui viewport command",
)

# -- the protobuf wire format, for the few viewer-control messages used ---------------------------


def _varint(n: int) -> bytes:
    """Base-128 varint, least significant group first; negative numbers as 64-bit two's complement."""
    n &= (1 << 64) - 1
    out = bytearray()
    while True:
        low, n = n & 0x7F, n >> 7
        out.append(low | (0x80 if n else 0))
        if not n:
            return bytes(out)


def field(number: int, value: int | str | bytes) -> bytes:
    """One field: an int as a varint (wire type 0), str/bytes length-delimited (wire type 2)."""
    if isinstance(value, int):
        return _varint(number << 3) + _varint(value)
    data = value.encode() if isinstance(value, str) else value
    return _varint(number << 3 | 2) + _varint(len(data)) + data


def parse(data: bytes) -> list[tuple[int, int | bytes]]:
    """The (field number, value) pairs of one message level: varints as int, the rest as bytes."""
    out, i = [], 0

    def varint():
        nonlocal i
        value = shift = 0
        while True:
            byte = data[i]
            i += 1
            value |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                return value

    while i < len(data):
        key = varint()
        number, wire = key >> 3, key & 7
        if wire == 0:
            out.append((number, varint()))
        elif wire == 2:
            n = varint()
            out.append((number, data[i : i + n]))
            i += n
        elif wire in (1, 5):  # fixed 64 / 32 bits
            width = 8 if wire == 1 else 4
            out.append((number, data[i : i + width]))
            i += width
        else:
            raise ValueError(f"protobuf wire type {wire} at byte {i}")
    return out


def _get(message: bytes, number: int) -> list:
    return [v for n, v in parse(message) if n == number]


# ViewerControlRequest/Response: one field per operation
GET_STATE, SET_TIME, GET_BLUEPRINT, SET_BLUEPRINT, GET_LOGS = 3, 6, 12, 14, 2


def set_time_request(timeline: str, value: int) -> bytes:
    """Move the cursor to `value` (nanoseconds or a sequence index) on `timeline`, paused."""
    # SetTimeCursorRequest: timeline = 2 (Timeline: name = 1), time = 3 (TimelineTime: time = 1),
    # play_state = 5 (PLAY_STATE_PAUSED = 1)
    return field(SET_TIME, field(2, field(1, timeline)) + field(3, field(1, value)) + field(5, 1))


def set_blueprint_request(blueprint: dict) -> bytes:
    """Replace the active recording's blueprint (SetBlueprintRequest: json = 2, recording = 3)."""
    return field(SET_BLUEPRINT, field(2, json.dumps(blueprint)) + field(3, b""))


# -- the viewer --------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, process: subprocess.Popen, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if process.poll() is not None:
            raise RuntimeError(f"rerun exited with status {process.returncode}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
            return
        time.sleep(0.2)
    raise RuntimeError(f"the web viewer did not listen on 127.0.0.1:{port} within {timeout:.0f} s")


@contextlib.contextmanager
def serve(recording: Path):
    """`rerun --serve-web` on the recording, on 127.0.0.1 only; yields the viewer's page URL."""
    beside = Path(sys.executable).with_name("rerun")  # this environment's rerun-sdk first
    rerun = str(beside) if beside.exists() else shutil.which("rerun")
    if rerun is None:
        raise RuntimeError("no rerun command (pip install rerun-sdk)")
    grpc, web = _free_port(), _free_port()
    log = tempfile.TemporaryFile()
    # its own process group: `rerun` is a launcher whose viewer binary must stop with it
    process = subprocess.Popen(
        [
            rerun,
            "--serve-web",
            "--bind",
            "127.0.0.1",
            "--port",
            str(grpc),
            "--web-viewer-port",
            str(web),
            str(recording),
        ],
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        _wait_for_port(web, process, 60)
        yield f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        log.close()


class Viewer:
    """The web viewer in a page: control requests in, decoded answers out."""

    def __init__(self, page):
        self.page = page

    def control(self, request: bytes) -> bytes:
        answer = self.page.evaluate(
            "async (b) => Array.from(await window._handle.viewer_control(new Uint8Array(b)))", list(request)
        )
        return bytes(answer)

    def state(self) -> bytes:
        return _get(self.control(field(GET_STATE, b"")), GET_STATE)[0]

    def wait_loaded(self, timeout: float) -> None:
        """Until the recording has arrived: a recording with timelines, nothing left loading."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with contextlib.suppress(Exception):
                state = self.state()
                recordings = _get(state, 3)
                if recordings and all(_get(r, 2) for r in recordings) and not _get(state, 7):
                    version = (_get(state, 6) or [b"?"])[0].decode()
                    if not version.startswith(VIEWER_VERSION):
                        print(f"warning: viewer {version}; the control messages are {VIEWER_VERSION}x's")
                    return
            time.sleep(0.5)
        raise RuntimeError(f"the recording did not load within {timeout:.0f} s")

    def timelines(self) -> dict[str, int]:
        """Timeline name -> its type (1 sequence, 2 duration, 3 timestamp)."""
        out = {}
        for recording in _get(self.state(), 3):
            for timeline in _get(recording, 2):
                name = _get(_get(timeline, 1)[0], 1)[0].decode()
                out[name] = (_get(timeline, 2) or [0])[0]
        return out

    def active_timeline(self) -> str | None:
        """The timeline the cursor is on (the one the blueprint's time panel names, once loaded)."""
        for recording in _get(self.state(), 3):
            for cursor in _get(recording, 3):
                return _get(_get(cursor, 1)[0], 1)[0].decode()
        return None

    def blueprint(self) -> dict:
        answer = _get(self.control(field(GET_BLUEPRINT, b"")), GET_BLUEPRINT)[0]
        return json.loads(_get(answer, 2)[0])

    def reports(self) -> list[str]:
        """The views' warnings and errors, as `view: severity: summary`."""
        out = []
        for view in _get(self.state(), 5):
            name = _get(view, 3)[0].decode()
            for report in _get(view, 6):
                out.append(f"{name}: {_get(report, 1)[0].decode()}: {_get(report, 2)[0].decode()}")
        return out

    def logs(self) -> list[str]:
        answer = _get(self.control(field(GET_LOGS, b"")), GET_LOGS)[0]
        return [f"{_get(e, 2)[0].decode()}: {_get(e, 4)[0].decode()}" for e in _get(answer, 1)]


def tabs(blueprint: dict) -> tuple[str, dict[str, str]]:
    """The root Tabs container's path and its tabs, display name -> blueprint path."""
    root = "/container/" + blueprint["/viewport"]["ViewportBlueprint"]["root_container"]
    container = blueprint[root]["ContainerBlueprint"]
    if container.get("container_kind") != "Tabs":
        return root, {}
    names = {}
    for k, path in enumerate(container["contents"]):  # entity paths, with or without the leading /
        entry = blueprint.get(path) or blueprint.get("/" + path.lstrip("/"), {})
        kind = entry.get("ContainerBlueprint") or entry.get("ViewBlueprint") or {}
        names[kind.get("display_name") or f"tab{k}"] = path
    return root, names


def with_active_tab(blueprint: dict, name: str) -> dict:
    root, names = tabs(blueprint)
    if name not in names:
        raise ValueError(f"--tab {name!r}: the recording's tabs are {', '.join(names) or 'none'}")
    out = json.loads(json.dumps(blueprint))
    out[root]["ContainerBlueprint"]["active_tab"] = names[name]
    return out


def timeline_cursor(value: str, kind: int) -> int:
    """`--at` in the timeline's unit: seconds -> ns on duration/timestamp timelines, else an index."""
    return int(round(float(value) * 1e9)) if kind in (2, 3) else int(value)


def _slug(text: str) -> str:
    return "-".join("".join(c if c.isalnum() or c in "_." else " " for c in text).split())


def shoot(
    recording: Path,
    out: Path,
    tab_names: list[str],
    at: list[str],
    timeline: str | None,
    size: tuple[int, int],
    settle: float,
) -> list[Path]:
    from playwright.sync_api import sync_playwright

    out.mkdir(parents=True, exist_ok=True)
    written = []
    with serve(recording) as url, sync_playwright() as p:  # playwright gives it a fresh temporary profile
        browser = p.chromium.launch(executable_path=chromium(), headless=True, args=CHROMIUM_FLAGS)
        try:
            page = browser.new_page(viewport={"width": size[0], "height": size[1]})
            errors = []
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(url)
            page.wait_for_function("window._handle !== undefined", timeout=120_000)
            viewer = Viewer(page)
            viewer.wait_loaded(120)
            time.sleep(settle)
            blueprint = viewer.blueprint()
            kinds = viewer.timelines()
            if at and timeline is None:
                timeline = viewer.active_timeline()
            if timeline is not None and timeline not in kinds:
                raise ValueError(f"--timeline {timeline!r}: the recording's are {', '.join(kinds)}")
            for name in tab_names or list(tabs(blueprint)[1]) or [""]:
                if name:
                    viewer.control(set_blueprint_request(with_active_tab(blueprint, name)))
                for value in at or [None]:
                    if value is not None:
                        viewer.control(set_time_request(timeline, timeline_cursor(value, kinds[timeline])))
                    time.sleep(settle)
                    path = out / (
                        _slug(name or "viewer") + (f"-{_slug(value)}" if value is not None else "") + ".png"
                    )
                    page.screenshot(path=str(path))
                    written.append(path)
                    print(path)
            for line in viewer.reports() + [m for m in viewer.logs() if not m.startswith("INFO")]:
                if not any(benign in line for benign in BENIGN):
                    print(f"viewer: {line}")
            for line in errors:
                if not any(benign in line for benign in BENIGN):
                    print(f"console: {line[:300]}")
        finally:
            browser.close()
    return written


def chromium() -> str | None:
    """The system's Chromium (or $CHROMIUM)."""
    for name in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if name and (path := shutil.which(name)):
            return path
    return None


def missing() -> str | None:
    """Why screenshots cannot be taken here, or None."""
    if chromium() is None:
        return "no Chromium found (apt-get install chromium, or set CHROMIUM)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install playwright; no browser download needed)"
    return None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("recording", type=Path, help=".rrd file")
    p.add_argument("out", type=Path, help="folder for the PNG files")
    p.add_argument("--tab", action="append", default=[], help="tab to show (default: every tab)")
    p.add_argument(
        "--at",
        action="append",
        default=[],
        help="time cursor: seconds, or an index on a sequence timeline (default: where the recording opens)",
    )
    p.add_argument("--timeline", help="timeline of --at (default: the one the recording opens on)")
    p.add_argument("--size", default="1600x900", help="viewport WIDTHxHEIGHT (default 1600x900)")
    p.add_argument("--settle", type=float, default=4.0, help="seconds to let the viewer draw (default 4)")
    args = p.parse_args(argv)
    if not args.recording.is_file():
        print(f"screenshots: {args.recording}: no such file", file=sys.stderr)
        return 2
    if why := missing():
        print(f"screenshots: skipped: {why}")
        return 0
    width, height = (int(v) for v in args.size.lower().split("x"))
    try:
        shoot(args.recording, args.out, args.tab, args.at, args.timeline, (width, height), args.settle)
    except ValueError as exc:
        print(f"screenshots: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

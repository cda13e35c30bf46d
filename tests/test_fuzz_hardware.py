"""scripts/fuzz_hardware.py at a tiny size: every part holds, and a broken decoder is caught."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "fuzz_hardware.py"
PARTS = (
    "frames",
    "altino replies",
    "watchdog",
    "actions",
    "stock altino",
    "faults",
    "model files",
    "params files",
)
CRC_CHECK = "if (fg_crc16(data, (size_t)n - 2u) != get_u16(data + n - 2)) {"
BOUND_CHECK = "if (dec->len < FG_MAX_FRAME) {"
WATCHDOG_CHECK = "(uint32_t)(now_us - dev->last_command_us) >= dev->watchdog_us"
needs_cc = pytest.mark.skipif(
    shutil.which("cc") is None and shutil.which("gcc") is None,
    reason="no C compiler: the C decoder cannot be built (apt-get install gcc)",
)


def fuzz(*options: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *options],
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
    )


@needs_cc
def test_every_part_holds_at_a_tiny_size():
    done = fuzz("--cases", "60", "--fault-rounds", "1", "--seed", "1")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    for name in PARTS:
        assert f"\n| {name} | " in done.stdout
    assert "ASan+UBSan" in done.stdout or "(no sanitizers)" in done.stderr
    assert done.stdout.rstrip().endswith("everything held")
    assert "frames: 60/60 streams" in done.stderr  # progress goes to stderr


def broken_firmware(
    tmp_path: Path, line: str, replacement: str, file: str = "fg_protocol.c"
) -> Path:
    """A copy of firmware/ with ``line`` of ``common/<file>`` replaced."""
    firmware = tmp_path / "firmware"
    shutil.copytree(ROOT / "firmware", firmware)
    source = firmware / "common" / file
    text = source.read_text()
    assert line in text
    source.write_text(text.replace(line, replacement))
    return firmware


@needs_cc
def test_a_c_decoder_that_skips_its_crc_check_is_caught(tmp_path):
    firmware = broken_firmware(tmp_path, CRC_CHECK, "if (0) {")
    done = fuzz("--part", "frames", "--cases", "300", "--firmware", str(firmware))
    assert done.returncode == 1, done.stdout[-3000:] + done.stderr[-2000:]
    assert "C decoded" in done.stdout
    assert "FAILED" in done.stdout


@needs_cc
def test_a_c_decoder_writing_past_its_buffer_is_caught(tmp_path):
    firmware = broken_firmware(tmp_path, BOUND_CHECK, "if (dec->len < FG_MAX_FRAME + 8u) {")
    done = fuzz("--part", "frames", "--cases", "300", "--firmware", str(firmware))
    assert done.returncode == 1, done.stdout[-3000:] + done.stderr[-2000:]
    if "(no sanitizers)" in done.stderr:
        pytest.skip("this compiler has no sanitizers: only the C == Python check ran")
    assert "out of bounds" in done.stdout


@needs_cc
def test_a_c_watchdog_that_waits_twice_as_long_is_caught(tmp_path):
    late = WATCHDOG_CHECK.replace(">= dev->watchdog_us", ">= 2u * dev->watchdog_us")
    firmware = broken_firmware(tmp_path, WATCHDOG_CHECK, late, "fg_device.c")
    done = fuzz("--part", "watchdog", "--cases", "400", "--firmware", str(firmware))
    assert done.returncode == 1, done.stdout[-3000:] + done.stderr[-2000:]
    assert "watchdog case" in done.stdout
    assert ": C motor " in done.stdout


def test_a_case_replays_alone():
    done = fuzz("--part", "params", "--first", "46", "--cases", "1", "--no-c")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "\n| params files | 1 | " in done.stdout
    assert "params files: 1/1 files" in done.stderr


def test_usage_errors_exit_2_with_one_line():
    done = fuzz("--part", "frames,nonsense")
    assert done.returncode == 2
    assert "unknown --part nonsense; choose from frames" in done.stderr
    assert fuzz("--cases", "0").returncode == 2


def test_help_names_every_option():
    done = fuzz("--help")
    assert done.returncode == 0, done.stderr
    for option in (
        "--cases",
        "--seed",
        "--part",
        "--first",
        "--fault-rounds",
        "--no-c",
        "--firmware",
    ):
        assert option in done.stdout

"""What the parts of ``fuzz_hardware.py`` share: the table of what each part tries and what
must hold, a part's record of its failures, per-case generators, and the C harness.

Imported by the ``_fuzz_*`` modules and ``fuzz_hardware.py`` (the scripts' folder is first on
``sys.path`` when it runs); not part of the package. Every case is drawn from
``random.Random(f"{seed}:{part}:{case}")``, so one failing case can be replayed alone.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
CFLAGS = ["-Wall", "-Wextra", "-Werror", "-std=c99", "-pedantic", "-g", "-O1"]
SANITIZERS = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
#: Longest a harness batch may take before it counts as hung, s.
BATCH_TIMEOUT = 600.0
Progress = Callable[[str], None]


#: What each part tries, and what every case of it must satisfy (the summary's columns).
WHAT: dict[str, tuple[str, str]] = {
    "frames": (
        "streams of 1-8 frames of every message type: intact, bit flips, truncated, extended, "
        "a byte replaced, garbage, bad CRC, good CRC over a bad layout, COBS edges; "
        "delimiters dropped or doubled; fed whole and in random pieces",
        "no exception but FrameError; every accepted frame is exactly a valid encoding; the "
        "result does not depend on the pieces; C (sanitized) == Python on every stream",
    ),
    "altino replies": (
        "stock Altino sensor replies (groups 1, 2, 10): intact, 1-3 bit flips, truncated, "
        "garbage, bad checksum, parsed alone and taken from a stream in random pieces",
        "no exception but ProtocolError/BadReply; every reply parsed is well-formed (start, "
        "length, end, checksum, group), every one taken from a stream too (but for its group, "
        "which the parser checks); the reader always finds the intact reply after",
    ),
    "watchdog": (
        "the servo and Altino firmware (fg_device.c and firmware.py) armed, sent commands "
        "at random times closer than its watchdog (the default, 5-50 ms or 100-400 ms; the "
        "Altino's driving away from the wall), then silence; clocks near the 32-bit µs wrap",
        "the motor holds while commands come and is 0 from the first tick at or past the "
        "watchdog time after the last command; C and Python agree tick by tick",
    ),
    "actions": (
        "device envs (servo and Altino) on the lock-step emulator over a pty, stepped with "
        "NaN, inf, huge floats and ints, strings, dates, None, complex, objects, bools, "
        "object arrays, wrong shapes, fractions, int64 extremes, between ordinary actions",
        "a refused action raises ValueError and zeroes the motor; the device never receives a "
        "command beyond its limit; non-numbers, non-finite and wrong shapes are refused; the "
        "run log holds every step that returned",
    ),
    "stock altino": (
        "the stock Altino backend driving a fake car on a pty at 50 Hz, each ordinary "
        "command followed by a hostile one (as for the actions)",
        "a refused command raises ValueError and the car receives the stop frames at once; "
        "no wheel value beyond 1000 and no malformed frame ever reaches the car",
    ),
    "faults": (
        "the servo env on the real-time emulator (500 Hz) stepped 20-200 times, then: the "
        "device unplugged, the device frozen (no more frames), or the host silent; a link "
        "delaying every frame by 0.12-0.3 s (the device's watchdog at 1 s); a link damaging "
        "1-10 % of the frames and dropping bytes, over 500 steps",
        "unplug/freeze raise DeviceDisconnectedError/DeviceTimeoutError, the delayed link a "
        "HardwareError within 25 steps with the motor zeroed, each with the log holding "
        "every step returned; after host silence the device's watchdog zeroes the motor "
        "within its time plus a period and the next step raises WatchdogTripError; over the "
        "damaging link every sample returned is the device's own state at its tick",
    ),
    "model files": (
        "copies of models/residual/rotary.zip carrying pickles (an added data entry, SB3's "
        "own entries, policy_kwargs, policy.pth or pytorch_variables.pth as a plain or a "
        "torch pickle), JSON values replaced, bits flipped, truncated; 1-3 at once",
        "nothing runs (no marker file, no pickle.find_class/os.system/subprocess audit "
        "event); the only error is ValueError (UnsafeModelError among them)",
    ),
    "params files": (
        "the two identified friction.json files with a value replaced (NaN, inf, 1e308, "
        "negative, strings, null, lists, 10^400, nesting up to 100 000 deep), a key dropped "
        "or doubled, bytes replaced, truncated, invalid UTF-8, another top-level value",
        "the only error is ParamsFileError; every file that loads has finite parameters "
        "inside their physical ranges",
    ),
}


@dataclass
class Part:
    """What one part of the fuzzing tried and what held."""

    name: str
    tried: str  #: what the cases were
    held: str  #: what every case had to satisfy
    cases: int = 0
    failures: list[str] = field(default_factory=list)
    #: Findings that are not failures (counts of known limits), printed under the table.
    notes: list[str] = field(default_factory=list)

    @classmethod
    def named(cls, name: str) -> Part:
        """The part ``name``, described by :data:`WHAT`."""
        return cls(name, *WHAT[name])

    def fail(self, message: str) -> None:
        """Record a failure (the first 20 are kept verbatim, the rest only counted)."""
        self.failures.append(message)


def progress(say: Progress, part: Part, cases: range, case: int, unit: str) -> None:
    """Say how far ``part`` got, ten times over its ``cases`` (``case`` just done)."""
    done = case + 1 - cases.start
    if done % max(1, len(cases) // 10) == 0:
        say(f"{part.name}: {done}/{len(cases)} {unit}, {len(part.failures)} failures")


def case_rng(seed: int, part: str, case: int) -> random.Random:
    """The generator of one case: a case can be replayed from its seed, part and number."""
    return random.Random(f"{seed}:{part}:{case}")


# --- the C harness ----------------------------------------------------------------------------


class HarnessBuildError(RuntimeError):
    """The C harness did not compile (the message holds the compiler's errors)."""


class CHarness:
    """firmware/test/host_harness.c built with the system compiler, run in batches.

    Built with AddressSanitizer and UBSan when the compiler links them (any report aborts the
    process, which then counts as a failure of its batch).
    """

    def __init__(self, workdir: Path, firmware: Path = FIRMWARE) -> None:
        compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
        if compiler is None:
            raise HarnessBuildError("no C compiler (cc or gcc) on PATH: install gcc or pass --no-c")
        sources = [*sorted((firmware / "common").glob("*.c")), firmware / "test" / "host_harness.c"]
        self.exe = workdir / "host_harness"
        self.sanitized = self._compile(compiler, [*CFLAGS, *SANITIZERS], sources)
        if not self.sanitized:
            self._compile(compiler, CFLAGS, sources, check=True)

    def _compile(
        self, compiler: str, flags: list[str], sources: list[Path], check: bool = False
    ) -> bool:
        done = subprocess.run(
            [compiler, *flags, *map(str, sources), "-o", str(self.exe)],
            capture_output=True,
            text=True,
            check=False,
        )
        if check and done.returncode != 0:
            raise HarnessBuildError(
                f"{compiler} failed on the C harness (or pass --no-c):\n{done.stderr}"
            )
        return done.returncode == 0

    def run(self, requests: list[str]) -> tuple[list[list[str]] | None, str]:
        """Answer ``requests``; return the answers (None if the process died) and its stderr."""
        text = "\n".join(requests) + "\nquit\n"
        done = subprocess.run(
            [str(self.exe)], input=text, capture_output=True, text=True, timeout=BATCH_TIMEOUT
        )
        answers = done.stdout.split("\n.\n")
        if done.returncode != 0 or len(answers) != len(requests) + 1:
            return None, done.stderr or f"exit status {done.returncode}"
        return [a.split("\n") if a else [] for a in answers[:-1]], done.stderr


def build_harness(
    firmware: Path | None,
) -> tuple[CHarness | None, tempfile.TemporaryDirectory[str] | None]:
    """Build the C harness of ``firmware`` (None: no C); the caller keeps the folder."""
    if firmware is None:
        return None, None
    folder = tempfile.TemporaryDirectory(prefix="fuzz-harness-")
    return CHarness(Path(folder.name), firmware), folder

"""Recordings: read from any format pcuvd reads, or made from arrays."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import _checks, _pcuvd

EVENT_AXES = ("events", "channels", "samples")


class Recording:
    """A recording: the acquisition (probe, angles, coding, f_s, PRF, t0 ...) and its samples.

    Samples have shape (events, channels, samples): float32 RF, or complex64 IQ with
    `demod_freq_hz`. Every quantity is in SI units, its unit in its name. The samples stay in the
    Rust library until `samples` is first read (a copy is then made once).
    """

    def __init__(self, native: Any):
        self._native = native
        self._acquisition = json.loads(native.acquisition_json())
        self._samples: np.ndarray | None = None

    # --- acquisition ---------------------------------------------------------------------
    @property
    def probe(self) -> dict:
        """The probe: name, n_elements, pitch_m, element_width_m, center_freq_hz, bandwidth
        (two-way −6 dB fraction of the centre frequency)."""
        return dict(self._acquisition["probe"])

    @property
    def sampling_freq_hz(self) -> float:
        """Sampling frequency of the traces (Hz)."""
        return self._acquisition["sampling_freq_hz"]

    @property
    def sound_speed_m_s(self) -> float:
        """Speed of sound assumed for the medium (m/s)."""
        return self._acquisition["sound_speed_m_s"]

    @property
    def t0_s(self) -> float:
        """Time of the first sample after the event's first pulse slot fires (s)."""
        return self._acquisition["t0_s"]

    @property
    def event_prf_hz(self) -> float:
        """Transmit-event repetition frequency (Hz)."""
        return self._acquisition["event_prf_hz"]

    @property
    def frame_rate_hz(self) -> float:
        """Compound frame rate = event PRF / angles (Hz): each angle's slow-time sampling rate."""
        return self._acquisition["frame_rate_hz"]

    @property
    def angles_rad(self) -> np.ndarray:
        """Steering angle of each slot (rad), > 0 tilting toward +x."""
        return np.array(self._acquisition["angles_rad"])

    @property
    def angles_deg(self) -> np.ndarray:
        """Steering angle of each slot (degrees)."""
        return np.degrees(self.angles_rad)

    @property
    def coding(self) -> str:
        """"none" (one angle per event), "hadamard" (every event fires every angle), "matrix"
        (an explicit code from a version 2 manifest: see `code_matrix` and `slot_starts_s`) or
        "decoded" (coded when fired, stored decoded: one record per angle, its stored polarity
        the diagonal of `code_matrix`, nothing decoded again)."""
        return self._acquisition["coding"]

    @property
    def slot_delay_s(self) -> float | None:
        """Delay between successive Hadamard pulse slots (s); None when not coded or uneven."""
        return self._acquisition["slot_delay_s"]

    @property
    def code_matrix(self) -> np.ndarray:
        """The transmit code, shape (events per frame, angles): entry (i, k) is the weight (±1,
        or 0 when silent) of angle k in event i of a compound frame; the identity when not coded,
        the stored polarities on the diagonal when decoded in the file."""
        return np.array(self._acquisition["code_matrix"], dtype=float)

    @property
    def slot_starts_s(self) -> np.ndarray:
        """When each angle's slot fires within its event (s), shape (angles,)."""
        return np.array(self._acquisition["slot_starts_s"], dtype=float)

    @property
    def transmit_pulse(self) -> tuple[np.ndarray, float] | None:
        """The transmit pulse as sampled (samples, sampling frequency in Hz), or None when only
        `pulse_cycles` is known. The simulator sends it through the probe's response."""
        pulse = self._acquisition["transmit_pulse"]
        if pulse is None:
            return None
        return np.array(pulse["samples"], dtype=float), float(pulse["sampling_freq_hz"])

    @property
    def pulse_cycles(self) -> float:
        """Transmit pulse length (cycles of the centre frequency)."""
        return self._acquisition["pulse_cycles"]

    @property
    def demod_freq_hz(self) -> float | None:
        """Demodulation frequency of IQ samples (Hz); None for RF."""
        return self._acquisition["demod_freq_hz"]

    @property
    def is_iq(self) -> bool:
        """True for complex baseband samples, False for RF."""
        return self._acquisition["demod_freq_hz"] is not None

    @property
    def shape(self) -> tuple[int, int, int]:
        """(events, channels, samples)."""
        a = self._acquisition
        return (a["n_events"], a["n_channels"], a["n_samples"])

    @property
    def n_frames(self) -> int:
        """Compound frames (events / angles)."""
        return self._acquisition["n_frames"]

    @property
    def n_angles(self) -> int:
        """Steering angles per compound frame."""
        return self._acquisition["n_angles"]

    @property
    def nyquist_velocity_m_s(self) -> float:
        """Largest unaliased projection velocity c·f_frame/(4 f_c) (m/s)."""
        return self._acquisition["nyquist_velocity_m_s"]

    @property
    def recorded_depth_m(self) -> float:
        """Deepest depth the traces reach (m)."""
        return self._acquisition["recorded_depth_m"]

    @property
    def files(self) -> list[str]:
        """Every file the recording was read from (empty for arrays and simulations)."""
        return list(self._acquisition["files"])

    @property
    def format(self) -> str:
        """The format it was read from, or what made it."""
        return self._acquisition["format"]

    @property
    def reader(self) -> str:
        """The reader that read it (or what made it)."""
        return self._acquisition["reader"]

    @property
    def parameters(self) -> dict:
        """Every acquisition parameter the reader resolved, by name (SI unit in the name):
        {"value": ..., "source": {"kind": "file" | "derived" | "default" | "override", ...}},
        e.g. parameters["t0_s"]["source"] == {"kind": "file", "field": "param.t0"}. Empty for
        arrays and simulations."""
        return {
            p["name"]: {"value": p["value"], "source": p["source"]}
            for p in self._acquisition.get("parameters", [])
        }

    @property
    def warnings(self) -> list[str]:
        """What the reader wants you to know (a default taken, a field not applied)."""
        return list(self._acquisition.get("warnings", []))

    @property
    def samples(self) -> np.ndarray:
        """The samples, (events, channels, samples): float32 RF or complex64 IQ (read-only)."""
        if self._samples is None:
            samples = self._native.samples()
            samples.flags.writeable = False
            self._samples = samples
        return self._samples

    def __repr__(self) -> str:
        kind = "IQ" if self.is_iq else "RF"
        return (
            f"<pcuvd.Recording {self.format}: {self.n_frames} frames × {self.n_angles} angles "
            f"({self.coding}), {kind} {self.shape}, f_s {self.sampling_freq_hz / 1e6:g} MHz, "
            f"frame rate {self.frame_rate_hz:g} Hz>"
        )

    # --- construction --------------------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        samples: Any,
        *,
        probe: str | dict,
        sampling_freq_hz: float,
        t0_s: float,
        event_prf_hz: float,
        angles_rad: Sequence[float],
        sound_speed_m_s: float = 1540.0,
        coding: str = "none",
        slot_delay_s: float | None = None,
        demod_freq_hz: float | None = None,
        pulse_cycles: float = 2.0,
        axes: Sequence[str] = EVENT_AXES,
    ) -> Recording:
        """A recording from arrays you hold.

        samples: RF (real: int16, float32, float64) or IQ (complex, with `demod_freq_hz`), with
        axes named by `axes` in any order of "events", "channels", "samples" (events = frames ×
        angles, the angles of a compound frame consecutive). probe: a preset name ("L22-14vX",
        "L11-5v") or a dict (n_elements, pitch_m, element_width_m, center_freq_hz, bandwidth;
        "preset" fills what is left out). coding: "none" or "hadamard" (needs `slot_delay_s`).
        """
        array = np.asarray(samples)
        array = _checks.reorder("samples", array, axes, EVENT_AXES)
        number = _checks.finite_number
        acquisition = {
            "probe": probe,
            "sampling_freq_hz": number("sampling_freq_hz", sampling_freq_hz),
            "t0_s": number("t0_s", t0_s, positive=False),
            "event_prf_hz": number("event_prf_hz", event_prf_hz),
            "angles_rad": [
                number("angles_rad", a, positive=False) for a in np.atleast_1d(angles_rad)
            ],
            "sound_speed_m_s": number("sound_speed_m_s", sound_speed_m_s),
            "coding": coding,
            "slot_delay_s": None
            if slot_delay_s is None
            else number("slot_delay_s", slot_delay_s, positive=False),
            "pulse_cycles": number("pulse_cycles", pulse_cycles),
        }
        text = json.dumps(acquisition, allow_nan=False)
        if array.dtype.kind == "c" or demod_freq_hz is not None:
            iq = _checks.complex64("samples", array, EVENT_AXES)
            native = _pcuvd.recording_from_arrays(
                iq=iq, demod_freq_hz=demod_freq_hz, acquisition=text
            )
        else:
            rf = _checks.real32("samples", array, EVENT_AXES)
            native = _pcuvd.recording_from_arrays(rf=rf, acquisition=text)
        return cls(native)


def read_recording(path: str | os.PathLike, **overrides: Any) -> Recording:
    """Reads a recording in any format `pcuvd process` reads (see the README's "What goes in"),
    recognised from its content, with the same reader as the command, whole into memory
    (`pcuvd.process(path)` reads a block of frames at a time instead).

    overrides: acquisition fields that replace (or fill in) what the file says, in SI units:
    sampling_freq_hz, sound_speed_m_s, t0_s, event_prf_hz, center_freq_hz, angles_rad, coding
    ("none", "hadamard"), slot_delay_s, pulse_cycles, bandwidth (fractional, 0.6 = 60 %), track
    (a zea file's track by index or label, a URX file's recorded group by index or description);
    `parameters` then names them as given by the user (a MUST file without param.t0 reads with
    t0_s=...). Raises OSError when the file cannot be opened, ValueError when its content or an
    override is unusable (the message the CLI prints, its options named as keywords), TypeError when `path` is not a path.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(
            f"read_recording() expects the path of a recording, got {type(path).__name__}"
        )
    native = _pcuvd.read_recording(os.fspath(path), reader_overrides(overrides))
    return Recording(native)


def reader_overrides(overrides: dict[str, Any] | None) -> str:
    """The reader's acquisition overrides as the JSON the native half reads (arrays as lists);
    a value that is not finite is a ValueError naming its field (JSON has no NaN)."""
    plain = {
        key: value.tolist() if isinstance(value, np.ndarray) else value
        for key, value in (overrides or {}).items()
    }
    return _checks.finite_json(plain)

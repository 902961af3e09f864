"""A streaming stationary-noise suppressor for the wake detector (16 kHz mono int16).

Short-time spectral analysis (32 ms square-root Hann windows, 16 ms hop), a per-bin
noise-floor estimate by minimum statistics (the minimum of the smoothed power over the
last ~1.5 s, times a bias factor: speech leaves every bin now and then, stationary noise
never does), and a Wiener gain from a decision-directed a-priori SNR (Ephraim & Malah),
which keeps the residual noise smooth instead of "musical" (isolated spectral peaks
that a detector could take for speech). The gain never drops below ``GAIN_FLOOR``.

It is causal and streaming: any chunking gives the same output samples (the input is
cut into exact hops inside), delayed by ``DELAY_SAMPLES``. Until it has heard ~1.5 s of
a noise it passes that noise's onset through nearly untouched (the minimum still holds
the quieter past). Pure numpy.
"""

from __future__ import annotations

import numpy as np

WINDOW = 512  # samples (32 ms at 16 kHz) per analysis window
HOP = 256  # samples (16 ms) between windows; 5 hops per 80 ms wake frame
DELAY_SAMPLES = WINDOW - HOP  # output lags input by this many samples (16 ms)
POWER_SMOOTHING = 0.8  # recursive smoothing of each bin's power per hop (~80 ms)
MIN_SUBWINDOW_HOPS = 12  # minimum statistics: sub-window length (192 ms)
MIN_SUBWINDOWS = 8  # sub-windows kept: the minimum spans 8 x 192 ms = 1.5 s
NOISE_BIAS = 2.0  # the minimum of a smoothed noise power underestimates its mean
DD_ALPHA = 0.96  # decision-directed a-priori SNR: weight of the previous hop's estimate
GAIN_FLOOR = 0.15  # lowest gain per bin (-16.5 dB): keeps some noise, no holes
EPS = 1e-10


class NoiseSuppressor:
    """Streaming minimum-statistics Wiener filter; ``process`` takes any chunk of int16."""

    def __init__(
        self,
        noise_bias: float = NOISE_BIAS,
        gain_floor: float = GAIN_FLOOR,
        dd_alpha: float = DD_ALPHA,
        min_subwindows: int = MIN_SUBWINDOWS,
    ) -> None:
        if not 0 < gain_floor <= 1:
            raise ValueError(f"gain floor must be in (0, 1], got {gain_floor}")
        if noise_bias <= 0 or min_subwindows < 1 or not 0 <= dd_alpha < 1:
            raise ValueError("noise bias > 0, min_subwindows >= 1 and dd_alpha in [0, 1) needed")
        self.noise_bias, self.gain_floor, self.dd_alpha = noise_bias, gain_floor, dd_alpha
        self.min_subwindows = min_subwindows
        self._window = np.sqrt(np.hanning(WINDOW + 1)[:WINDOW])  # periodic sqrt-Hann: COLA at 50 %
        self.reset()

    def reset(self) -> None:
        bins = WINDOW // 2 + 1
        self._in = np.zeros(WINDOW, dtype=np.float64)  # the last WINDOW input samples
        self._pending = np.zeros(0, dtype=np.float64)  # input not yet a whole hop
        self._overlap = np.zeros(HOP, dtype=np.float64)  # second half of the last output window
        self._power: np.ndarray | None = None  # smoothed power per bin
        self._sub_min = np.full(bins, np.inf)  # minimum in the current sub-window
        self._sub_hops = 0
        self._mins: list[np.ndarray] = []  # minima of the last complete sub-windows
        self._prev_clean = np.zeros(bins)  # |G X|^2 of the last hop (decision-directed)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """int16 samples in → as many int16 samples out (the stream delayed by DELAY_SAMPLES)."""
        x = np.concatenate([self._pending, np.asarray(chunk, dtype=np.float64).ravel()])
        n = len(x) // HOP
        self._pending = x[n * HOP :]
        out = np.empty(n * HOP, dtype=np.float64)
        for i in range(n):
            out[i * HOP : (i + 1) * HOP] = self._hop(x[i * HOP : (i + 1) * HOP])
        return np.clip(np.rint(out), -32768, 32767).astype(np.int16)

    def _hop(self, hop: np.ndarray) -> np.ndarray:
        self._in = np.concatenate([self._in[HOP:], hop])
        spec = np.fft.rfft(self._in * self._window)
        power = spec.real**2 + spec.imag**2
        noise = self._track_noise(power) + EPS
        gamma = power / noise  # a-posteriori SNR
        prior = self.dd_alpha * self._prev_clean / noise
        xi = np.maximum(prior + (1 - self.dd_alpha) * np.maximum(gamma - 1, 0), EPS)
        gain = np.maximum(xi / (1 + xi), self.gain_floor)  # Wiener gain on the a-priori SNR
        self._prev_clean = gain**2 * power
        frame = np.fft.irfft(spec * gain, WINDOW) * self._window
        out = self._overlap + frame[:HOP]
        self._overlap = frame[HOP:]
        return out

    def _track_noise(self, power: np.ndarray) -> np.ndarray:
        """This hop's power per bin → the noise power per bin (minimum statistics)."""
        a = POWER_SMOOTHING
        self._power = power.copy() if self._power is None else a * self._power + (1 - a) * power
        self._sub_min = np.minimum(self._sub_min, self._power)
        self._sub_hops += 1
        if self._sub_hops >= MIN_SUBWINDOW_HOPS:
            self._mins = [*self._mins[-(self.min_subwindows - 1) :], self._sub_min] \
                if self.min_subwindows > 1 else [self._sub_min]  # fmt: skip
            self._sub_min = np.full_like(power, np.inf)
            self._sub_hops = 0
        noise: np.ndarray = self.noise_bias * np.minimum.reduce([*self._mins, self._sub_min])
        return noise

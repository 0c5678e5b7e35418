"""The paper's three one-at-a-time studies, as data: the cases every reproduction and the solver study run.

Each study varies one quantity from the nominal plant (Table 1, KP = 1e5, KI = 0.001, KD = 0):

* c1 = 2.25e6, 2.25e5, 1.25e5 N s/m (paper Figs. 4, 5)
* Ct = 5e-16, 5e-10, 5e-9 m^3/(s Pa) (Figs. 6, 7)
* KP = 1e5, 3.5e6, 3.9e6 V/m (Figs. 8, 9)
"""

from __future__ import annotations

from dataclasses import dataclass

from millvib_env.params import PAPER_GAINS, MillParams, PIDGains

__all__ = ["PaperCase", "PaperStudy", "PAPER_STUDIES"]


@dataclass(frozen=True)
class PaperCase:
    label: str
    value: float
    params: MillParams
    gains: PIDGains


@dataclass(frozen=True)
class PaperStudy:
    key: str
    symbol: str
    unit: str
    figures: str
    claim_direction: str
    claim_kind: str
    cases: tuple[PaperCase, ...]


def _study(key: str, symbol: str, unit: str, values, figures: str, direction: str, kind: str) -> PaperStudy:
    cases = []
    for v in values:
        if key == "KP":
            params, gains = MillParams(), PIDGains(v, PAPER_GAINS.ki, PAPER_GAINS.kd)
        else:
            params, gains = MillParams().replace(**{key: v}), PAPER_GAINS
        cases.append(PaperCase(f"{symbol} = {v:.3g}", v, params, gains))
    return PaperStudy(key, symbol, unit, figures, direction, kind, tuple(cases))


PAPER_STUDIES: tuple[PaperStudy, ...] = (
    _study("c1", "c1", "N s/m", (2.25e6, 2.25e5, 1.25e5), "Figs. 4-5",
           "severity rises as the damping c1 falls",
           "stable -> periodic vibration as c1 falls"),
    _study("Ct", "Ct", "m^3/(s Pa)", (5.0e-16, 5.0e-10, 5.0e-9), "Figs. 6-7",
           "severity rises with the leakage Ct",
           "convergent -> multi-period vibration as Ct grows"),
    _study("KP", "KP", "V/m", (1.0e5, 3.5e6, 3.9e6), "Figs. 8-9",
           "severity rises with the gain KP",
           "convergent -> periodic -> quasi-periodic as KP grows"),
)

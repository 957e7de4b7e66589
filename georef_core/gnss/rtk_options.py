"""Options of the PPK engine, with defaults, and the reading of RTKLIB rnx2rtkp configuration files."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputFileError
from .constants import NAVSYS_BITS


@dataclass
class RtkOptions:
    # --- positioning mode and signals
    mode: str = "kinematic"            # kinematic | static | known-start (single-frequency Daakir mode) | single
    n_bands: int = 2                   # 1 = L1 only, 2 = L1+L2 (E5b for Galileo, B2 for BeiDou), 3 = +L5
    systems: tuple[str, ...] = ("G", "R", "E", "J", "C")
    filter_direction: str = "combined"  # forward | backward | combined
    reverse_witness: bool = True       # forward/backward: the other pass runs too and refutes contradicted fixes
    ubx_event_edge: str = "falling"    # the TIM-TM2 edge of a UBX rover log that marks the exposure (ubx.py)
    elevation_mask_deg: float = 15.0
    snr_mask_dbhz: float = 0.0         # 0 = off
    excluded_sats: tuple[str, ...] = ()
    # --- ambiguity resolution
    ar_mode: str = "fix-and-hold"      # off | continuous | instantaneous | fix-and-hold
    glonass_ar: bool = True
    bds_ar: bool = True
    ratio_threshold: float = 3.0
    min_success_rate: float = 0.0     # bootstrapped success rate a fix needs besides the ratio test (0 = off)
    ar_min_lock_epochs: int = 0
    ar_elevation_mask_deg: float = 0.0
    ar_min_fix_to_hold: int = 10
    hold_elevation_mask_deg: float = 0.0
    hold_variance_cyc2: float = 0.1    # fix-and-hold: variance of the held DD ambiguities (demo5's default)
    ar_filter: bool = True             # new signals that bring a fix down to a marginal ratio wait (demo5's arfilter)
    partial_ar: bool = True
    partial_ar_max_drop: int = 4
    partial_ar_max_float_sigma_m: float = 0.3   # subsets are searched only once the float position is this good
    min_ambiguities_to_fix: int = 4
    fix_max_sigma_m: float = 0.05      # a fixed epoch whose 3-D sigma exceeds this is output as float (0 = off; fix_precision.py)
    outage_reset_epochs: int = 5
    max_age_s: float = 30.0
    base_interpolation: bool = True    # interpolate base observations between base epochs (else the nearest base epoch)
    # --- atmosphere
    troposphere: str = "saastamoinen"  # saastamoinen | hopfield | off
    ionosphere: str = "broadcast"      # broadcast | off (single point positioning; see dd_ionosphere)
    # In double differences over short baselines the models' differential delays are what matters:
    # the hydrostatic part is well modelled; the standard atmosphere's wet part and Klobuchar's spatial
    # gradient are guesses below their own error. Defaults follow RTKLIB's relative mode.
    dd_troposphere_humidity: float = 0.7   # relative humidity used in DD (0 = hydrostatic delay only, as RTKLIB)
    dd_ionosphere: bool = False            # apply the broadcast ionosphere in double differences too
    # --- cycle slips and outliers
    slip_gf_threshold_m: float = 0.05
    slip_doppler_threshold_cyc: float = 0.0   # 0 = off
    slip_tdcp_threshold_m: float = 0.05       # time-differenced phase fit residual (tdcp_slips); 0 = off
    reject_innovation_m: float = 30.0
    # --- noise model (sigma_phase^2 = 2 (a^2 + (b / sin el)^2), sigma_code = f * sigma_phase)
    phase_error_a_m: float = 0.002
    phase_error_b_m: float = 0.002
    code_phase_ratio: tuple[float, ...] = (100.0, 100.0, 100.0)
    phase_error_baseline_m_per_10km: float = 0.0
    doppler_error_hz: float = 10.0
    clock_stability: float = 5e-12
    glonass_error_factor: float = 1.5
    # --- process noise
    initial_bias_sigma_cyc: float = 30.0
    bias_process_noise_cyc: float = 1e-4
    dynamics: str = "off"              # off (position re-initialised each epoch) | random-walk | constant-velocity
    position_random_walk_m_sqrt_s: float = 1.0
    accel_noise_h_m_s2: float = 10.0
    accel_noise_v_m_s2: float = 10.0
    # --- positions
    base_position_ecef_m: tuple[float, float, float] | None = None   # None = RINEX header
    known_start_position_ecef_m: tuple[float, float, float] | None = None   # known-start mode
    known_start_sigma_m: float = 0.02
    base_antenna_delta_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rover_antenna_delta_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_baseline_km: float = 100.0

    def validate(self) -> None:
        choices = {
            "mode": ("kinematic", "static", "known-start", "single"),
            "filter_direction": ("forward", "backward", "combined"),
            "ubx_event_edge": ("falling", "rising"),
            "ar_mode": ("off", "continuous", "instantaneous", "fix-and-hold"),
            "troposphere": ("saastamoinen", "hopfield", "off"),
            "ionosphere": ("broadcast", "off"),
            "dynamics": ("off", "random-walk", "constant-velocity"),
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"option {name}={getattr(self, name)!r}: expected one of {', '.join(allowed)}")
        if self.n_bands not in (1, 2, 3):
            raise ValueError(f"option n_bands={self.n_bands}: expected 1, 2 or 3")
        if self.mode == "known-start" and self.known_start_position_ecef_m is None:
            raise ValueError("mode known-start needs the take-off position (--known-start LAT,LON,H or X,Y,Z)")
        if not 0 <= self.elevation_mask_deg < 90:
            raise ValueError("elevation mask must be within [0, 90) degrees")
        if not 1e-6 <= self.hold_variance_cyc2 <= 100:
            raise ValueError(f"hold variance {self.hold_variance_cyc2} cycles^2: expected 1e-6 to 100")
        if not 0 <= self.fix_max_sigma_m <= 10:
            raise ValueError(f"fix precision limit {self.fix_max_sigma_m} m: expected 0 (off) to 10 m")
        if not 0 <= self.slip_tdcp_threshold_m <= 1:
            raise ValueError(f"time-differenced slip threshold {self.slip_tdcp_threshold_m} m: expected 0 (off) to 1 m")

    def replace(self, **changes) -> "RtkOptions":
        return dataclasses.replace(self, **changes)


# ---------------------------------------------------------------- RTKLIB configuration files

_POSMODE = {"kinematic": "kinematic", "static": "static", "single": "single", "movingbase": None,
            "fixed": None, "ppp-kine": None, "ppp-static": None, "ppp-fixed": None, "dgps": None,
            "static-start": "kinematic"}
_FREQ = {"l1": 1, "l1+l2": 2, "l1+2": 2, "l1+l2+l5": 3, "l1+2+3": 3}
_SOLTYPE = {"forward": "forward", "backward": "backward", "combined": "combined", "combined-nophasereset": "combined"}
_ARMODE = {"off": "off", "continuous": "continuous", "instantaneous": "instantaneous", "fix-and-hold": "fix-and-hold"}
_TROP = {"off": "off", "saas": "saastamoinen", "hopfield": "hopfield"}
_IONO = {"off": "off", "brdc": "broadcast"}
_IGNORED_OUTPUT_KEYS = {  # output formatting and file options: they do not change the solution
    "out-solformat", "out-outhead", "out-outopt", "out-timesys", "out-timeform", "out-timendec", "out-degform",
    "out-height", "out-solstatic", "out-outstat", "out-fieldsep", "out-outvel", "out-nmeaintv1", "out-nmeaintv2",
    "out-geoid", "out-maxsolstd", "file-satantfile", "file-rcvantfile", "file-staposfile", "file-geoidfile",
    "file-dcbfile", "file-tracefile", "file-ionofile", "file-blqfile", "file-eopfile", "file-solstatfile",
    "file-cmdfile1", "file-cmdfile2", "file-cmdfile3", "file-tempdir", "file-geexefile", "file-solstatfile",
    "misc-svrcycle", "misc-timeout", "misc-reconnect", "misc-nmeacycle", "misc-buffsize", "misc-navmsgsel",
    "misc-proxyaddr", "misc-fswapmargin", "misc-sbasatsel", "misc-rnxopt1", "misc-rnxopt2", "misc-pppopt",
    "pos1-sateph", "pos1-tidecorr", "ant1-anttype", "ant2-anttype", "stats-errdoppler",
}


@dataclass
class RtklibConfResult:
    options: RtkOptions
    applied: dict[str, str] = field(default_factory=dict)
    unsupported: dict[str, str] = field(default_factory=dict)   # key -> reason
    unknown: list[str] = field(default_factory=list)


def read_rtklib_conf(path, base: RtkOptions | None = None) -> RtklibConfResult:
    """Map an rnx2rtkp/RTKPOST configuration onto RtkOptions. Every key is either applied,
    reported as unsupported (with the reason) or reported as unknown; nothing is silently dropped."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "RTKLIB configuration file not found")
    opts = dataclasses.replace(base or RtkOptions())
    res = RtklibConfResult(opts)
    ant1_type = "llh"
    ant1 = [0.0, 0.0, 0.0]
    ant2_type, ant2 = "rinexhead", [0.0, 0.0, 0.0]
    for lineno, raw in enumerate(p.read_text(errors="replace").splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if "=" not in line:
            raise InputFileError(p, f"expected 'key = value', got {raw.strip()!r}", lineno)
        key, value_full = (s.strip() for s in line.split("=", 1))
        value = value_full.split()[0] if value_full.split() else ""
        key_l, val_l = key.lower(), value.lower()

        def bad(reason):
            res.unsupported[key] = f"{value}: {reason}"

        def num():
            try:
                return float(value)
            except ValueError:
                raise InputFileError(p, f"{key}: {value!r} is not a number", lineno) from None

        def setopt(attr, v):
            setattr(opts, attr, v)
            res.applied[key] = value

        if key_l == "pos1-posmode":
            m = _POSMODE.get(val_l)
            if m is None:
                bad("positioning mode not supported (kinematic, static, single are)")
            else:
                setopt("mode", m)
        elif key_l == "pos1-frequency":
            if val_l not in _FREQ:
                bad("expected l1, l1+l2 or l1+l2+l5")
            else:
                setopt("n_bands", _FREQ[val_l])
        elif key_l == "pos1-soltype":
            if val_l not in _SOLTYPE:
                bad("expected forward, backward or combined")
            else:
                setopt("filter_direction", _SOLTYPE[val_l])
        elif key_l == "pos1-elmask":
            setopt("elevation_mask_deg", num())
        elif key_l in ("pos1-snrmask_r", "pos1-snrmask_b"):
            if val_l != "off":
                bad("SNR mask per elevation bin not supported; use --snr-mask")
            else:
                res.applied[key] = value
        elif key_l == "pos1-dynamics":
            setopt("dynamics", "constant-velocity" if val_l == "on" else "off")
        elif key_l == "pos1-ionoopt":
            if val_l not in _IONO:
                bad("only off and brdc are supported")
            else:
                setopt("ionosphere", _IONO[val_l])
        elif key_l == "pos1-tropopt":
            if val_l not in _TROP:
                bad("only off, saas and hopfield are supported (no estimation)")
            else:
                setopt("troposphere", _TROP[val_l])
        elif key_l == "pos1-sateph":
            if val_l != "brdc":
                bad("only broadcast ephemeris is supported")
            else:
                res.applied[key] = value
        elif key_l == "pos1-tidecorr":
            if val_l not in ("off", "0"):
                bad("tide corrections not supported")
            else:
                res.applied[key] = value
        elif key_l == "pos1-exclsats":
            opts.excluded_sats = tuple(value_full.replace(",", " ").split())
            res.applied[key] = value_full
        elif key_l == "pos1-navsys":
            bits = int(num())
            systems = tuple(s for s, b in NAVSYS_BITS.items() if bits & b and s in ("G", "R", "E", "J", "C"))
            if bits & (NAVSYS_BITS["S"] | NAVSYS_BITS["I"]):
                res.unsupported[key + " (SBAS/NavIC)"] = "SBAS and NavIC are not used"
            setopt("systems", systems)
        elif key_l == "pos2-armode":
            if val_l not in _ARMODE:
                bad("expected off, continuous, instantaneous or fix-and-hold")
            else:
                setopt("ar_mode", _ARMODE[val_l])
        elif key_l == "pos2-gloarmode":
            if val_l in ("on", "off"):
                setopt("glonass_ar", val_l == "on")
            else:
                bad("GLONASS inter-channel bias calibration modes are not supported; on or off")
        elif key_l == "pos2-bdsarmode":
            setopt("bds_ar", val_l == "on")
        elif key_l == "pos2-arthres":
            setopt("ratio_threshold", num())
        elif key_l == "pos2-arlockcnt":
            setopt("ar_min_lock_epochs", int(num()))
        elif key_l == "pos2-arelmask":
            setopt("ar_elevation_mask_deg", num())
        elif key_l == "pos2-arminfix":
            setopt("ar_min_fix_to_hold", int(num()))
        elif key_l == "pos2-elmaskhold":
            setopt("hold_elevation_mask_deg", num())
        elif key_l == "pos2-varholdamb":
            setopt("hold_variance_cyc2", num())
        elif key_l == "pos2-arfilter":
            if val_l in ("on", "off", "1", "0"):
                setopt("ar_filter", val_l in ("on", "1"))
            else:
                bad("expected on or off")
        elif key_l == "pos2-aroutcnt":
            setopt("outage_reset_epochs", int(num()))
        elif key_l == "pos2-maxage":
            setopt("max_age_s", num())
        elif key_l == "pos2-slipthres":
            setopt("slip_gf_threshold_m", num())
        elif key_l == "pos2-rejionno":
            setopt("reject_innovation_m", num())
        elif key_l == "pos2-niter":
            if num() > 1:
                bad("filter iterations > 1 not supported (one EKF update per epoch)")
            else:
                res.applied[key] = value
        elif key_l in ("pos2-baselen", "pos2-basesig"):
            if num() != 0:
                bad("baseline-length constraint not supported")
            else:
                res.applied[key] = value
        elif key_l == "stats-eratio1":
            opts.code_phase_ratio = (num(),) + tuple(opts.code_phase_ratio[1:])
            res.applied[key] = value
        elif key_l == "stats-eratio2":
            opts.code_phase_ratio = (opts.code_phase_ratio[0], num(), opts.code_phase_ratio[2])
            res.applied[key] = value
        elif key_l == "stats-eratio5":
            opts.code_phase_ratio = (opts.code_phase_ratio[0], opts.code_phase_ratio[1], num())
            res.applied[key] = value
        elif key_l == "stats-errphase":
            setopt("phase_error_a_m", num())
        elif key_l == "stats-errphaseel":
            setopt("phase_error_b_m", num())
        elif key_l == "stats-errphasebl":
            setopt("phase_error_baseline_m_per_10km", num())
        elif key_l == "stats-errdoppler":
            setopt("doppler_error_hz", num())
        elif key_l == "stats-stdbias":
            setopt("initial_bias_sigma_cyc", num())
        elif key_l == "stats-prnbias":
            setopt("bias_process_noise_cyc", num())
        elif key_l == "stats-prnaccelh":
            setopt("accel_noise_h_m_s2", num())
        elif key_l == "stats-prnaccelv":
            setopt("accel_noise_v_m_s2", num())
        elif key_l == "stats-clkstab":
            setopt("clock_stability", num())
        elif key_l in ("stats-stdiono", "stats-stdtrop", "stats-prniono", "stats-prntrop"):
            res.applied[key] = value + " (used only when ionosphere/troposphere are estimated; they are not)"
        elif key_l == "ant1-postype":
            ant1_type = val_l
            res.applied[key] = value
        elif key_l in ("ant1-pos1", "ant1-pos2", "ant1-pos3"):
            ant1[int(key_l[-1]) - 1] = num()
            res.applied[key] = value
        elif key_l == "ant2-postype":
            ant2_type = val_l
            if val_l not in ("llh", "xyz", "rinexhead"):
                bad("base position types supported: llh, xyz, rinexhead")
            else:
                res.applied[key] = value
        elif key_l in ("ant2-pos1", "ant2-pos2", "ant2-pos3"):
            ant2[int(key_l[-1]) - 1] = num()
            res.applied[key] = value
        elif key_l in ("ant1-antdele", "ant1-antdeln", "ant1-antdelu", "ant2-antdele", "ant2-antdeln", "ant2-antdelu"):
            idx = "enu".index(key_l[-1])
            attr = "rover_antenna_delta_enu_m" if key_l.startswith("ant1") else "base_antenna_delta_enu_m"
            cur = list(getattr(opts, attr))
            cur[idx] = num()
            setattr(opts, attr, tuple(cur))
            res.applied[key] = value
        elif key_l == "misc-timeinterp":
            setopt("base_interpolation", val_l == "on")
        elif key_l in _IGNORED_OUTPUT_KEYS:
            res.applied[key] = value + " (output/file setting, no effect on the solution)"
        elif key_l.startswith(("pos1-", "pos2-", "stats-", "ant1-", "ant2-", "misc-", "out-", "file-")):
            if val_l in ("", "off", "0"):
                res.applied[key] = value + " (off)"
            else:
                bad("option not supported by Georef")
        else:
            res.unknown.append(key)
    if ant2_type in ("llh", "xyz") and any(ant2):
        from .frames import geodetic_to_ecef_m

        if ant2_type == "llh":
            xyz = geodetic_to_ecef_m(math.radians(ant2[0]), math.radians(ant2[1]), ant2[2])
            opts.base_position_ecef_m = tuple(float(v) for v in xyz)
        else:
            opts.base_position_ecef_m = tuple(ant2)
    if any(ant1) and ant1_type in ("llh", "xyz"):
        res.unsupported["ant1-pos1..3"] = "fixed rover position is only used as the known start (use --known-start)"
    return res

"""Reading RTKLIB rnx2rtkp configuration files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.gnss.frames import geodetic_to_ecef_m
from georef_core.gnss.rtk_options import read_rtklib_conf

from .rtklib_cases import reference_cases


@pytest.mark.parametrize("case", reference_cases()[:: 7] or [None])
def test_reference_confs_are_fully_understood(case):
    if case is None:
        pytest.skip("shared data absent")
    res = read_rtklib_conf(case[5])
    assert res.unknown == [] and res.unsupported == {}
    o = res.options
    name = case[1]
    assert o.mode == name.split("_")[0]
    assert o.n_bands == (2 if "_l1l2_" in name else 1)
    assert o.filter_direction == ("combined" if "_comb_" in name else "forward")
    assert o.ar_mode == ("fix-and-hold" if name.endswith("fah") else "continuous")
    assert o.elevation_mask_deg == 15 and o.ratio_threshold == 3 and o.phase_error_a_m == 0.003


def test_values_and_positions(tmp_path):
    conf = tmp_path / "a.conf"
    conf.write_text("""# comment
pos1-posmode       =kinematic
pos1-navsys        =13   # GPS GLO GAL
pos1-exclsats      =G05 R11
pos2-gloarmode     =off
stats-eratio1      =300
stats-prnaccelh    =3
ant2-postype       =llh
ant2-pos1          =53.280449957
ant2-pos2          =-9.057836328
ant2-pos3          =66.8
ant2-antdelu       =0.1
pos1-ionoopt       =est-stec
pos2-varholdamb    =0.001
pos2-arfilter      =off
""")
    res = read_rtklib_conf(conf)
    o = res.options
    assert o.systems == ("G", "R", "E") and o.excluded_sats == ("G05", "R11")
    assert o.glonass_ar is False and o.code_phase_ratio[0] == 300 and o.accel_noise_h_m_s2 == 3
    expect = geodetic_to_ecef_m(math.radians(53.280449957), math.radians(-9.057836328), 66.8)
    assert np.allclose(o.base_position_ecef_m, expect, atol=1e-4)
    assert o.base_antenna_delta_enu_m == (0.0, 0.0, 0.1)
    assert "pos1-ionoopt" in res.unsupported  # reported, not silently ignored
    assert o.hold_variance_cyc2 == 0.001 and o.ar_filter is False
    defaults = read_rtklib_conf(tmp_path / "a.conf").options.__class__()
    assert defaults.hold_variance_cyc2 == 0.1 and defaults.ar_filter is True   # demo5's defaults


def test_malformed_conf_names_file_and_line(tmp_path):
    conf = tmp_path / "b.conf"
    conf.write_text("pos1-posmode =kinematic\nthis line has no equals sign\n")
    with pytest.raises(InputFileError, match=r"b.conf, line 2"):
        read_rtklib_conf(conf)
    conf.write_text("pos1-elmask =fifteen\n")
    with pytest.raises(InputFileError, match="not a number"):
        read_rtklib_conf(conf)

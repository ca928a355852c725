"""u-blox UBX reader (io/ubx.py): framing, checksums, damaged frames, slots, loss of lock."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from pyubx2 import GET, UBXMessage

from jaxnav.io import InputError
from jaxnav.io.ubx import read_ubx

WALK = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "gnss_imu_walk"
WEEK = 2381


def _rawx(tow, meas, clk_reset=0):
    fields = dict(rcvTow=tow, week=WEEK, leapS=18, numMeas=len(meas), recStat=clk_reset << 1)
    for i, m in enumerate(meas, 1):
        s = f"_{i:02d}"
        fields |= {k + s: v for k, v in m.items()}
    return UBXMessage("RXM", "RXM-RAWX", GET, **fields).serialize()


def _meas(gnss, sv, sig, lock_ms, half=1, pr=2.1e7):
    return dict(prMes=pr, cpMes=pr / 0.19, doMes=-50.0, gnssId=gnss, svId=sv, sigId=sig,
                locktime=lock_ms, cno=40, prValid=1, cpValid=1, halfCyc=half)


def _pvt(tow_ms):
    return UBXMessage("NAV", "NAV-PVT", GET, iTOW=tow_ms, fixType=3, lat=40.0, lon=-105.0,
                      height=1580000, velN=1000, velE=-2000, velD=500, hAcc=1500, vAcc=2500,
                      numSV=9).serialize()


def _log(lock_g5=(1000, 2000, 100, 1100), half_e7=(1, 1, 0, 1)):
    """Four 1-s epochs: G05 L1 with the given lock times, E07 E1 with halfCyc flags."""
    out = b""
    for k in range(4):
        meas = [_meas(0, 5, 0, lock_g5[k]), _meas(2, 7, 0, 5000 + 1000 * k, half=half_e7[k])]
        out += _rawx(100.0 + k, meas) + _pvt(100_000 + 1000 * k)
        out += b"$GNGGA,173021.75,4005.80,N,10508.83,W,4,12,0.62,1601.4,M,-21.4,M,0.8,0000*5C\r\n"
    return out


def test_observations_land_in_their_slots_with_rinex_codes_and_units(tmp_path):
    f = tmp_path / "a.ubx"
    f.write_bytes(_log())
    log = read_ubx(f)
    g, e = log.obs.systems["G"], log.obs.systems["E"]
    np.testing.assert_array_equal(log.obs.time_gps_s, WEEK * 604800 + 100.0 + np.arange(4))
    assert log.obs.interval_s == 1.0
    assert g.sv[4] == "G05" and e.sv[6] == "E07"
    np.testing.assert_allclose(g.obs["C1C"][:, 4], 2.1e7)
    np.testing.assert_allclose(g.obs["L1C"][:, 4], 2.1e7 / 0.19)
    assert np.isnan(g.obs["C1C"][:, 3]).all()  # an untracked slot stays missing
    np.testing.assert_allclose(log.pvt.llh[0], [math.radians(40.0), math.radians(-105.0), 1580.0])
    np.testing.assert_allclose(log.pvt.vel_enu[0], [-2.0, 1.0, -0.5])
    np.testing.assert_allclose(log.pvt.time_gps_s, log.obs.time_gps_s)
    assert log.counts["RXM-RAWX"] == 4 and log.counts["damaged"] == 0


def test_loss_of_lock_from_the_lock_time_and_the_half_cycle_flag(tmp_path):
    f = tmp_path / "a.ubx"
    f.write_bytes(_log(lock_g5=(1000, 2000, 100, 1100), half_e7=(1, 1, 0, 1)))
    log = read_ubx(f)
    # G05: arc start, continuous, lock restarted (100 ms < the 1-s epoch spacing), continuous
    np.testing.assert_array_equal(log.obs.systems["G"].lli["L1C"][:, 4], [1, 0, 1, 0])
    # E07: the half-cycle ambiguity unresolved at epoch 2 -> no phase there, a new arc after
    e = log.obs.systems["E"]
    assert np.isnan(e.obs["L1C"][2, 6]) and np.isfinite(e.obs["C1C"][2, 6])
    np.testing.assert_array_equal(e.lli["L1C"][:, 6], [1, 0, 0, 1])
    assert log.counts["half_cycle_unresolved"] == 1


def test_a_damaged_frame_is_counted_and_named_by_its_byte_offset(tmp_path):
    data = bytearray(_log())
    second = data.find(b"\xb5\x62\x02\x15", 10)  # the second RAWX frame
    data[second + 20] ^= 0xFF  # one payload byte: the checksum no longer matches
    f = tmp_path / "bad.ubx"
    f.write_bytes(bytes(data))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        log = read_ubx(f)
    text = [str(w.message) for w in got]
    assert len(text) == 2, text
    assert re.search(rf"1 damaged UBX frame.*byte offset {second}\b", text[0])
    assert "1 missing RXM-RAWX epoch" in text[1]
    assert log.counts["damaged"] == 1 and log.counts["RXM-RAWX"] == 3
    # that epoch is back on the grid, empty; the others are intact
    np.testing.assert_array_equal(log.obs.epoch_present, [True, False, True, True])
    np.testing.assert_array_equal(log.obs.time_gps_s, WEEK * 604800 + 100.0 + np.arange(4))
    g = log.obs.systems["G"]
    assert np.isnan(g.obs["C1C"][1]).all() and np.isfinite(g.obs["C1C"][2, 4])
    assert g.lli["L1C"][2, 4] == 1  # the phase after the gap starts a new arc


def test_a_frame_pyubx2_cannot_read_is_a_damaged_frame(tmp_path):
    """A checksummed RAWX whose measurement count disagrees with its length."""
    data = bytearray(_log())
    first = data.find(b"\xb5\x62\x02\x15")
    length = data[first + 4] | (data[first + 5] << 8)
    data[first + 6 + 11] += 1  # numMeas (payload byte 11) one too many
    end = first + 8 + length
    a = b = 0
    for byte in data[first + 2 : end - 2]:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    data[end - 2 : end] = bytes((a, b))
    f = tmp_path / "badcount.ubx"
    f.write_bytes(bytes(data))
    with pytest.warns(UserWarning, match=rf"1 damaged UBX frame.*byte offset {first}\b"):
        log = read_ubx(f)
    assert log.counts["damaged"] == 1 and log.counts["RXM-RAWX"] == 3


def test_a_sub_half_cycle_change_and_an_off_grid_epoch(tmp_path):
    out = b""
    for k, sub in enumerate((0, 0, 1, 1)):
        m = _meas(0, 5, 0, 5000 + 1000 * k) | {"subHalfCyc": sub}
        out += _rawx(100.0 + k, [m])
    f = tmp_path / "sub.ubx"
    f.write_bytes(out)
    log = read_ubx(f)
    # the receiver moved the phase by half a cycle at epoch 2: a new arc there
    np.testing.assert_array_equal(log.obs.systems["G"].lli["L1C"][:, 4], [1, 0, 1, 0])
    f.write_bytes(_rawx(100.0, [_meas(0, 5, 0, 1000)]) + _rawx(101.0, [_meas(0, 5, 0, 2000)])
                  + _rawx(102.5, [_meas(0, 5, 0, 3000)]))
    with pytest.raises(InputError, match="500.0 ms off the 1-s grid"):
        read_ubx(f)


def test_a_truncated_file_and_stray_bytes_are_reported(tmp_path):
    data = _log()
    f = tmp_path / "cut.ubx"
    f.write_bytes(data[:7] + b"\x00\x13\x37" + data[7:-10])
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        log = read_ubx(f)
    text = " ".join(str(w.message) for w in got)
    assert "damaged UBX frame" in text and "neither UBX nor NMEA" in text
    assert log.counts["damaged"] >= 1 and log.counts["unrecognised_bytes"] >= 1


def test_a_file_without_raw_measurements_is_an_input_error(tmp_path):
    f = tmp_path / "pvt.ubx"
    f.write_bytes(_pvt(1000) + _pvt(2000))
    with pytest.raises(InputError, match="no UBX-RXM-RAWX"):
        read_ubx(f)


@pytest.mark.skipif(not WALK.is_dir(), reason="../shared/data/gnss_imu_walk is absent")
def test_the_walk_log_reads_whole():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the shipped file has no damaged frame
        log = read_ubx(WALK / "gnss_1730.ubx")
    assert log.counts["damaged"] == 0 and log.counts["unrecognised_bytes"] == 0
    t = log.obs.time_gps_s
    assert t.size == log.counts["RXM-RAWX"] and np.allclose(np.diff(t), 0.25, atol=1e-3)
    assert 130.0 < t[-1] - t[0] < 140.0  # "about 134 s" (data README)
    g = log.obs.systems["G"]
    assert {"C1C", "C2L", "C5Q", "L1C", "L2L", "L5Q", "D1C"} <= set(g.obs)
    # pseudoranges of MEO satellites seen from the ground
    c = g.obs["C1C"][np.isfinite(g.obs["C1C"])]
    assert c.min() > 1.9e7 and c.max() < 2.7e7
    # one NAV-PVT per RAWX epoch: the same epoch, apart by the receiver clock (ms)
    assert np.max(np.abs(log.pvt.time_gps_s - t)) < 0.125

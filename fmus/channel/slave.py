"""V2XChannel FMU: one directed V2X link (transmitter -> receiver) behind FMI 2.

A thin wrapper of fmus.channel.model.ChannelModel.evaluate_one: at
initialisation and after every step the outputs are the model's answer for
the current inputs (the channel has no state: the same inputs and seed give
the same outputs whatever the step size). Bad inputs (NaN position,
negative size or seq, negative walls) raise, which pythonfmu turns into
fmi2Error with the message in the FMU log; bad parameters fail
fmi2ExitInitializationMode naming the parameter.
"""
from __future__ import annotations

from dataclasses import fields

from fmus.channel.model import ChannelModel, ChannelParams
from fmus.slave_base import V2iSlave, Var

_P = ChannelParams()

_INPUTS = (
    Var("tx_x", "input", "Transmitter position x (world frame, east)", "m", 0.0),
    Var("tx_y", "input", "Transmitter position y (world frame, north)", "m", 0.0),
    Var("tx_z", "input", "Transmitter position z (ground under the antenna; antenna height is added)", "m", 0.0),
    Var("rx_x", "input", "Receiver position x (world frame, east)", "m", 100.0),
    Var("rx_y", "input", "Receiver position y (world frame, north)", "m", 0.0),
    Var("rx_z", "input", "Receiver position z (ground under the antenna; antenna height is added)", "m", 0.0),
    Var("walls", "input", "Building walls crossed by the direct path (from the world geometry)", start=0,
        type="Integer"),
    Var("inside_m", "input", "Length of the direct path inside buildings (from the world geometry)", "m", 0.0),
    Var("packet_bytes", "input", "Size of the current packet (application bytes, >= 1)", start=190, type="Integer"),
    Var("seq", "input", "Sequence number of the current packet (>= 0): keys its loss and latency draws",
        start=0, type="Integer"),
)

_STRING_PARAMETERS = (
    Var("technology", "parameter", "Radio: 'dsrc' (IEEE 802.11p) or 'cv2x' (LTE-V2X sidelink mode 4)",
        start=_P.technology, type="String"),
    Var("pathloss_model", "parameter", "Path loss: 'winner_b1' (WINNER+ B1 LOS, TR 36.885), 'tr37885_urban' "
        "(3GPP TR 37.885 V2V urban) or 'free_space'", start=_P.pathloss_model, type="String"),
    Var("error_model", "parameter", "Packet error curve: 'lut' (802.11p: Goubet et al. 2015 FER; C-V2X: R1-160284 "
        "BLER; both measured over vehicular channels) or 'nist' (802.11p over AWGN, Veins NistErrorRate)",
        start=_P.error_model, type="String"),
    Var("fading", "parameter", "Small-scale fading: 'none' or 'nakagami' (Veins: m = 1.5 below 80 m, 0.75 beyond; "
        "meant with error_model 'nist', the LUT curves already include fading)", start=_P.fading, type="String"),
    Var("obstacle_model", "parameter", "Building loss: 'sommer' (per wall + per metre inside, Sommer et al. 2011), "
        "'tr37885_nlos' (TR 37.885 NLOS formula when walls > 0) or 'none'", start=_P.obstacle_model,
        type="String"),
)

_REAL_PARAMETERS = (
    Var("freq_ghz", "parameter", "Carrier frequency", "GHz", _P.freq_ghz),
    Var("tx_power_dbm", "parameter", "Transmit power", "dBm", _P.tx_power_dbm),
    Var("tx_gain_dbi", "parameter", "Transmit antenna gain", "dBi", _P.tx_gain_dbi),
    Var("rx_gain_dbi", "parameter", "Receive antenna gain", "dBi", _P.rx_gain_dbi),
    Var("tx_antenna_height_m", "parameter", "Transmit antenna height above tx_z", "m", _P.tx_antenna_height_m),
    Var("rx_antenna_height_m", "parameter", "Receive antenna height above rx_z", "m", _P.rx_antenna_height_m),
    Var("env_height_m", "parameter", "Effective environment height of WINNER+ B1 (breakpoint uses h - h_env)", "m",
        _P.env_height_m),
    Var("noise_figure_db", "parameter", "Receiver noise figure", "dB", _P.noise_figure_db),
    Var("bandwidth_hz", "parameter", "Channel bandwidth", "Hz", _P.bandwidth_hz),
    Var("data_rate_bps", "parameter", "802.11p data rate (10 MHz: 3, 4.5, 6, 9, 12, 18, 24, 27 Mb/s)", "bit/s",
        _P.data_rate_bps),
    Var("sensing_threshold_dbm", "parameter", "Sensing / preamble detection threshold; 0 = technology default "
        "(-85 dBm 802.11p, -90.5 dBm C-V2X)", "dBm", _P.sensing_threshold_dbm),
    Var("shadowing_sigma_db", "parameter", "Log-normal shadowing std; negative = the path-loss model's own "
        "(B1 3 dB, TR 37.885 3 dB LOS / 4 dB NLOS, free space 0)", "dB", _P.shadowing_sigma_db),
    Var("decorrelation_m", "parameter", "Shadowing decorrelation distance (TR 37.885 V2V urban: 10 m)", "m",
        _P.decorrelation_m),
    Var("wall_loss_db", "parameter", "Loss per wall crossed (Veins default 9 dB)", "dB", _P.wall_loss_db),
    Var("inside_loss_db_per_m", "parameter", "Loss per metre inside buildings (Veins default 0.4 dB/m)", "dB/m",
        _P.inside_loss_db_per_m),
    Var("min_distance_m", "parameter", "Path-loss formulas use max(distance, this)", "m", _P.min_distance_m),
    Var("density_veh_per_m", "parameter", "Channel load: vehicle density on the road (0 = no load model)", "1/m",
        _P.density_veh_per_m),
    Var("cbr_target", "parameter", "Channel load as a channel busy ratio (0 = use density_veh_per_m); converted "
        "to the density giving this CBR in the load model", "1", _P.cbr_target),
    Var("msg_rate_hz", "parameter", "Message rate of every vehicle (load model, SPS reservation interval)", "Hz",
        _P.msg_rate_hz),
    Var("processing_s", "parameter", "Device processing (stack, security) added to every latency", "s",
        _P.processing_s),
    Var("sps_t1_ms", "parameter", "C-V2X SPS selection window start T1 (<= 4 ms)", "ms", _P.sps_t1_ms),
    Var("sps_t2_ms", "parameter", "C-V2X SPS selection window end T2 (20..100 ms)", "ms", _P.sps_t2_ms),
    Var("sps_keep_prob", "parameter", "C-V2X probability of keeping the reservation at counter expiry", "1",
        _P.sps_keep_prob),
    Var("loss_prob", "parameter", "Extra packet loss whatever the radio conditions, in [0, 1) (what-if studies; "
        "0 = none): a frame the channel would deliver is dropped with this probability", "1", _P.loss_prob),
)

_INTEGER_PARAMETERS = (
    Var("cv2x_subchannels", "parameter", "C-V2X subchannels (4: QPSK r~0.7 over 10 RBs; 2: QPSK r=0.5 over 12 RBs)",
        start=_P.cv2x_subchannels, type="Integer"),
    Var("load_packet_bytes", "parameter", "Packet size of the other vehicles (load model)",
        start=_P.load_packet_bytes, type="Integer"),
    Var("mac_header_bytes", "parameter", "802.11p MAC/LLC overhead added to packet_bytes on air (Sepulcre: 30)",
        start=_P.mac_header_bytes, type="Integer"),
    Var("aifsn", "parameter", "802.11p EDCA AIFSN (1609.4 CCH AC_VO: 2)", start=_P.aifsn, type="Integer"),
    Var("cw_min", "parameter", "802.11p EDCA CWmin (1609.4 CCH AC_VO: 3)", start=_P.cw_min, type="Integer"),
    Var("seed", "parameter", "Random seed: shadowing field and per-packet draws", start=_P.seed, type="Integer"),
)

_LINK_PARAMETERS = (
    Var("tx_id", "parameter", "Transmitter station id (keys the per-packet draws)", start=0, type="Integer"),
    Var("rx_id", "parameter", "Receiver station id (keys the per-packet draws)", start=1, type="Integer"),
)

_OUTPUTS = (
    Var("distance_m", "output", "Distance between the antennas", "m"),
    Var("path_loss_db", "output", "Path loss including building loss (no shadowing, no fading)", "dB"),
    Var("obstacle_loss_db", "output", "Building loss part of path_loss_db", "dB"),
    Var("shadowing_db", "output", "Shadowing of this link at the current positions (positive = gain)", "dB"),
    Var("fading_db", "output", "Fading power gain of the current packet", "dB"),
    Var("rx_power_dbm", "output", "Received power of the current packet", "dBm"),
    Var("snr_db", "output", "SNR of the current packet (C-V2X: over its data resource blocks)", "dB"),
    Var("per", "output", "Loss probability of the current packet (propagation, decoding, load)", "1"),
    Var("pdr", "output", "Expected packet delivery ratio at this distance and obstruction "
        "(averaged over shadowing, fading and load)", "1"),
    Var("delivered", "output", "Whether the current packet is received", start=False, type="Boolean"),
    Var("latency_s", "output", "Latency of the current packet if delivered: access + airtime + propagation + "
        "processing", "s"),
    Var("cbr", "output", "Channel busy ratio of the load model (0 without load)", "1"),
)

_PARAMETER_NAMES = tuple(f.name for f in fields(ChannelParams))
_RESULTS = ("distance_m", "path_loss_db", "obstacle_loss_db", "shadowing_db", "fading_db", "rx_power_dbm", "snr_db",
            "per", "pdr", "delivered", "latency_s")


class V2XChannel(V2iSlave):
    """One directed V2X link: path loss, buildings, shadowing, fading, PER, load, latency."""

    DESCRIPTION = (
        "V2X radio channel of one directed link for IEEE 802.11p (DSRC) or LTE-V2X mode 4: WINNER+ B1 / "
        "TR 37.885 / free-space path loss, Sommer building loss, correlated shadowing, Nakagami fading, "
        "link-level PER curves, and the analytical load models of Sepulcre et al. (IEEE TVT 2021) and "
        "Gonzalez-Martin et al. (IEEE TVT 2019); per-packet delivery and latency reproducible from seed and seq."
    )
    DEFAULT_STEP = 0.1
    VARIABLES = _INPUTS + _STRING_PARAMETERS + _REAL_PARAMETERS + _INTEGER_PARAMETERS + _LINK_PARAMETERS + _OUTPUTS

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model: ChannelModel | None = None

    def initialize(self) -> None:
        v = self.values
        self.model = ChannelModel(ChannelParams(**{name: v[name] for name in _PARAMETER_NAMES})).prepare()
        v["cbr"] = float(self.model.cbr)
        self._evaluate()

    def step(self, t: float, dt: float) -> None:
        self._evaluate()

    def _evaluate(self) -> None:
        v = self.values
        result = self.model.evaluate_one((v["tx_x"], v["tx_y"], v["tx_z"]), (v["rx_x"], v["rx_y"], v["rx_z"]),
                                         v["walls"], v["inside_m"], v["packet_bytes"], v["seq"],
                                         v["tx_id"], v["rx_id"])
        for name in _RESULTS:
            v[name] = result[name]

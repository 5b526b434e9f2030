"""Real-time correction inside a running controller (KUKA RSI, ABB EGM): the model corrects every
interpolation cycle. Sits above :mod:`hykin.compensation` (it runs its warm ``Compensator``).

* :mod:`.udp_bridge` — the UDP loop shared by the bridges: one controller, drops, counts, stop rule.
* :mod:`.rsi_xml` — KUKA RSI Ethernet XML messages and ``RSI_EthernetConfig.xml``.
* :mod:`.rsi` — ``hykin rsi``: the correction of each RSI setpoint.
* :mod:`.egm` — ``hykin egm``: ABB EGM pose guidance; :mod:`.egm_pb2` is generated from ``egm.proto`` (ABB's).
* :mod:`.simulated` — simulated controllers that run at the real period (tests, benchmarks).
"""

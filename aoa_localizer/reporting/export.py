"""The estimates for GIS tools: GeoJSON and KML with, per emitter (channel), the point and the 95 % ellipse as a
real lat/lon polygon (and the same for each transmitter of a channel several share), and each station's track;
time, algorithm, bearing count, channel and frequency as properties."""
from __future__ import annotations

import datetime
import xml.etree.ElementTree as ET

import numpy as np

from aoa_localizer.common.xml_text import xml_text
from aoa_localizer.engine.crlb import ellipse_axes, ellipse_points
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.types import Estimate

KML_NS = "http://www.opengis.net/kml/2.2"


def properties(est: Estimate) -> dict:
    a, b, azimuth = ellipse_axes(est.cov)
    timed = bool(np.isfinite(est.stamp))  # a survey without times has none
    return {"time": datetime.datetime.fromtimestamp(est.stamp, datetime.UTC).isoformat() if timed else None,
            "stamp": est.stamp if timed else None, "algorithm": est.algorithm, "bearings_used": est.bearings_used,
            "points_used": est.points_used, "ellipse95_semi_major_m": round(a, 2),
            "ellipse95_semi_minor_m": round(b, 2), "ellipse95_major_azimuth_deg": round(azimuth, 1),
            "channel": est.channel,
            "frequency_hz": est.frequency_hz if np.isfinite(est.frequency_hz) else None}


def names(est: Estimate) -> tuple[str, str]:
    """The point's and the ellipse's names: plain for the default channel, with the channel and frequency else."""
    if est.channel == "default":
        return "emitter estimate", "95 % error ellipse"
    mhz = f" ({est.frequency_hz / 1e6:.3f} MHz)" if np.isfinite(est.frequency_hz) else ""
    return f"emitter {est.channel}{mhz}", f"95 % error ellipse {est.channel}"


def shown(estimates: list[Estimate]) -> list[tuple[Estimate, str, str, dict]]:
    """What is drawn for each estimate, with its point's and ellipse's names and properties of its own: the
    estimate, then each transmitter of a channel that several share (co-channel), as an estimate at its place."""
    out: list[tuple[Estimate, str, str, dict]] = []
    for est in estimates:
        point_name, ellipse_name = names(est)
        out.append((est, point_name, ellipse_name, {}))
        for k, t in enumerate(est.transmitters, start=1):
            out.append((est.at_transmitter(t), f"{point_name}: transmitter {k} of {len(est.transmitters)}",
                        f"{ellipse_name}: transmitter {k} of {len(est.transmitters)}",
                        {"share": round(t.share, 4), "state": str(t.state),
                         "count_probability": round(est.count_probability, 4)}))
    return out


def track_name(station: str) -> str:
    return f"vehicle track {station}" if station else "vehicle track"


def moving_by_channel(estimates: list[Estimate]) -> dict[str, list[Estimate]]:
    """Each channel's `moving` estimates in time order: its path as a moving transmitter."""
    by_channel: dict[str, list[Estimate]] = {}
    for est in sorted(estimates, key=lambda e: e.stamp):
        if est.motion == "moving":
            by_channel.setdefault(est.channel, []).append(est)
    return by_channel


def moving_paths(estimates: list[Estimate]) -> dict[str, np.ndarray]:
    """Each channel's path as a moving transmitter (its `moving` estimates' places in time order, ENU rows east,
    north), where it has two or more."""
    return {channel: np.array([(e.east, e.north) for e in ests])
            for channel, ests in moving_by_channel(estimates).items() if len(ests) >= 2}


def path_name(channel: str) -> str:
    return "transmitter path" if channel == "default" else f"transmitter path {channel}"


def _lonlat(frame: LocalFrame, enu: np.ndarray) -> list[list[float]]:
    lat, lon, _ = frame.to_geodetic(enu[:, 0], enu[:, 1])
    return [[float(x), float(y)] for x, y in zip(np.atleast_1d(lon), np.atleast_1d(lat), strict=False)]


def ellipse_ring(frame: LocalFrame, est: Estimate) -> list[list[float]]:
    """The 95 % ellipse as a closed (lon, lat) ring."""
    ring = _lonlat(frame, ellipse_points((est.east, est.north), est.cov))
    ring[-1] = ring[0]
    return ring


def region_rings(est: Estimate) -> list[tuple[str, list[list[list[float]]]]]:
    """The estimate's highest-density regions (the survey model's), if any: (name, closed (lon, lat) rings) per
    level."""
    out = []
    for level, rings in sorted((est.regions or {}).items()):
        closed = [[[float(lon), float(lat)] for lat, lon in ring] for ring in rings]
        out.append((f"{100 * level:.0f} % region {names(est)[0]}", [r + [r[0]] if r[0] != r[-1] else r
                                                                      for r in closed]))
    return out


def geojson(frame: LocalFrame, estimates: list[Estimate], tracks: dict[str, np.ndarray],
            paths: dict[str, np.ndarray] | None = None) -> dict:
    """A FeatureCollection: per emitter its estimate (Point), 95 % ellipse (Polygon) and, where it has them, its
    highest-density regions (MultiPolygon) and its path as a moving transmitter (`paths`: LineString); per station
    its track (LineString, ENU rows east, north)."""
    features = []
    for est in estimates:
        for name, rings in region_rings(est):
            features.append({"type": "Feature",
                             "geometry": {"type": "MultiPolygon", "coordinates": [[r] for r in rings]},
                             "properties": {"name": name, "channel": est.channel}})
    for est, point_name, ellipse_name, own in shown(estimates):
        props = {**properties(est), **own}
        features += [
            {"type": "Feature", "geometry": {"type": "Point", "coordinates": [est.lon, est.lat]},
             "properties": {"name": point_name, **props}},
            {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ellipse_ring(frame, est)]},
             "properties": {"name": ellipse_name, **props}},
        ]
    for station, track_enu in tracks.items():
        if len(track_enu) >= 2:
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "LineString", "coordinates": _lonlat(frame, track_enu)},
                    "properties": {"name": track_name(station)},
                }
            )
    for channel, path in (paths or {}).items():
        features.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": _lonlat(frame, path)},
                         "properties": {"name": path_name(channel), "channel": channel}})
    return {"type": "FeatureCollection", "features": features}


def kml(frame: LocalFrame, estimates: list[Estimate], tracks: dict[str, np.ndarray],
        paths: dict[str, np.ndarray] | None = None) -> str:
    """A KML document with the same placemarks (opens in Google Earth and GIS tools)."""
    ET.register_namespace("", KML_NS)
    q = lambda tag: f"{{{KML_NS}}}{tag}"  # noqa: E731
    root = ET.Element(q("kml"))
    doc = ET.SubElement(root, q("Document"))
    algorithms = ", ".join(sorted({est.algorithm for est in estimates}))
    ET.SubElement(doc, q("name")).text = xml_text(f"aoa_localizer: emitter estimates ({algorithms})")

    def placemark(name: str, props: dict | None):
        pm = ET.SubElement(doc, q("Placemark"))
        ET.SubElement(pm, q("name")).text = xml_text(name)
        if props is not None:
            if props["time"] is not None:
                ET.SubElement(ET.SubElement(pm, q("TimeStamp")), q("when")).text = props["time"]
            data = ET.SubElement(pm, q("ExtendedData"))
            for key, value in props.items():
                ET.SubElement(ET.SubElement(data, q("Data"), name=key), q("value")).text = xml_text(value)
        return pm

    coords = lambda pts: " ".join(f"{lon:.8f},{lat:.8f},0" for lon, lat in pts)  # noqa: E731
    for est, point_name, ellipse_name, own in shown(estimates):
        props = {**properties(est), **own}
        point = ET.SubElement(placemark(point_name, props), q("Point"))
        ET.SubElement(point, q("coordinates")).text = coords([[est.lon, est.lat]])
        poly = ET.SubElement(placemark(ellipse_name, props), q("Polygon"))
        ring = ET.SubElement(ET.SubElement(poly, q("outerBoundaryIs")), q("LinearRing"))
        ET.SubElement(ring, q("coordinates")).text = coords(ellipse_ring(frame, est))
        for name, rings in region_rings(est):
            multi = ET.SubElement(placemark(name, None), q("MultiGeometry"))
            for r in rings:
                boundary = ET.SubElement(ET.SubElement(multi, q("Polygon")), q("outerBoundaryIs"))
                ET.SubElement(ET.SubElement(boundary, q("LinearRing")), q("coordinates")).text = coords(r)
    lines = [(track_name(station), enu) for station, enu in tracks.items() if len(enu) >= 2]
    for name, enu in lines + [(path_name(channel), path) for channel, path in (paths or {}).items()]:
        line = ET.SubElement(placemark(name, None), q("LineString"))
        ET.SubElement(line, q("coordinates")).text = coords(_lonlat(frame, enu))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"

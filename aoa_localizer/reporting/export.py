"""The estimate for GIS tools: GeoJSON and KML with the point, the 95 % ellipse as a real lat/lon polygon,
and the vehicle track; time, algorithm and bearing count as properties."""
from __future__ import annotations

import datetime
import xml.etree.ElementTree as ET

import numpy as np

from aoa_localizer.engine.crlb import ellipse_axes, ellipse_points
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.types import Estimate

KML_NS = "http://www.opengis.net/kml/2.2"


def properties(est: Estimate) -> dict:
    a, b, azimuth = ellipse_axes(est.cov)
    return {"time": datetime.datetime.fromtimestamp(est.stamp, datetime.UTC).isoformat(),
            "stamp": est.stamp, "algorithm": est.algorithm, "bearings_used": est.bearings_used,
            "points_used": est.points_used, "ellipse95_semi_major_m": round(a, 2),
            "ellipse95_semi_minor_m": round(b, 2), "ellipse95_major_azimuth_deg": round(azimuth, 1)}


def _lonlat(frame: LocalFrame, enu: np.ndarray) -> list[list[float]]:
    lat, lon, _ = frame.to_geodetic(enu[:, 0], enu[:, 1], np.zeros(len(enu)))
    return [[float(x), float(y)] for x, y in zip(np.atleast_1d(lon), np.atleast_1d(lat), strict=False)]


def ellipse_ring(frame: LocalFrame, est: Estimate) -> list[list[float]]:
    """The 95 % ellipse as a closed (lon, lat) ring."""
    ring = _lonlat(frame, ellipse_points((est.east, est.north), est.cov))
    ring[-1] = ring[0]
    return ring


def geojson(frame: LocalFrame, est: Estimate, track_enu: np.ndarray) -> dict:
    """A FeatureCollection: the estimate (Point), its 95 % ellipse (Polygon), the vehicle track (LineString)."""
    props = properties(est)
    features = [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [est.lon, est.lat]},
         "properties": {"name": "emitter estimate", **props}},
        {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ellipse_ring(frame, est)]},
         "properties": {"name": "95 % error ellipse", **props}},
    ]
    if len(track_enu) >= 2:
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": _lonlat(frame, track_enu)},
                "properties": {"name": "vehicle track"},
            }
        )
    return {"type": "FeatureCollection", "features": features}


def kml(frame: LocalFrame, est: Estimate, track_enu: np.ndarray) -> str:
    """A KML document with the same three placemarks (opens in Google Earth and GIS tools)."""
    ET.register_namespace("", KML_NS)
    q = lambda tag: f"{{{KML_NS}}}{tag}"  # noqa: E731
    root = ET.Element(q("kml"))
    doc = ET.SubElement(root, q("Document"))
    ET.SubElement(doc, q("name")).text = f"aoa_localizer: emitter estimate ({est.algorithm})"
    props = properties(est)

    def placemark(name: str, with_data: bool):
        pm = ET.SubElement(doc, q("Placemark"))
        ET.SubElement(pm, q("name")).text = name
        if with_data:
            ET.SubElement(ET.SubElement(pm, q("TimeStamp")), q("when")).text = props["time"]
            data = ET.SubElement(pm, q("ExtendedData"))
            for key, value in props.items():
                ET.SubElement(ET.SubElement(data, q("Data"), name=key), q("value")).text = str(value)
        return pm

    coords = lambda pts: " ".join(f"{lon:.8f},{lat:.8f},0" for lon, lat in pts)  # noqa: E731
    point = ET.SubElement(placemark("emitter estimate", True), q("Point"))
    ET.SubElement(point, q("coordinates")).text = coords([[est.lon, est.lat]])
    poly = ET.SubElement(placemark("95 % error ellipse", True), q("Polygon"))
    ring = ET.SubElement(ET.SubElement(poly, q("outerBoundaryIs")), q("LinearRing"))
    ET.SubElement(ring, q("coordinates")).text = coords(ellipse_ring(frame, est))
    if len(track_enu) >= 2:
        line = ET.SubElement(placemark("vehicle track", False), q("LineString"))
        ET.SubElement(line, q("coordinates")).text = coords(_lonlat(frame, track_enu))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"

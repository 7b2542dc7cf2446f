//! Parsing of the import's geographic options: `--clip-bbox`, `--clip-polygon` files
//! (GeoJSON or Osmosis `.poly`), `--origin`, and `x,y` pairs.

use std::path::Path;

use maps::LatLon;
use maps::build::{Clip, ClipPolygon};

/// Two comma-separated numbers.
pub fn parse_pair(s: &str) -> Result<(f64, f64), String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [a, b] = parts.as_slice() else {
        return Err(format!("expected two numbers `a,b`, not `{s}`"));
    };
    let a: f64 = a.parse().map_err(|_| format!("`{a}` is not a number"))?;
    let b: f64 = b.parse().map_err(|_| format!("`{b}` is not a number"))?;
    if !(a.is_finite() && b.is_finite()) {
        return Err(format!("`{s}` is not finite"));
    }
    Ok((a, b))
}

fn check_lat_lon(p: LatLon) -> Result<LatLon, String> {
    if p.lat.abs() > 90.0 || p.lon.abs() > 180.0 {
        Err(format!(
            "latitude {} / longitude {} out of range",
            p.lat, p.lon
        ))
    } else {
        Ok(p)
    }
}

/// `lat,lon`.
pub fn parse_lat_lon(s: &str) -> Result<LatLon, String> {
    let (lat, lon) = parse_pair(s)?;
    check_lat_lon(LatLon::new(lat, lon))
}

/// `minlon,minlat,maxlon,maxlat` (the order of OSM's and GeoJSON's bboxes).
pub fn parse_bbox(s: &str) -> Result<Clip, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [a, b, c, d] = parts.as_slice() else {
        return Err(format!("expected `minlon,minlat,maxlon,maxlat`, not `{s}`"));
    };
    let mut v = [0.0f64; 4];
    for (slot, text) in v.iter_mut().zip([a, b, c, d]) {
        *slot = text
            .parse()
            .map_err(|_| format!("`{text}` is not a number"))?;
        if !slot.is_finite() {
            return Err(format!("`{text}` is not finite"));
        }
    }
    let min = check_lat_lon(LatLon::new(v[1], v[0]))?;
    let max = check_lat_lon(LatLon::new(v[3], v[2]))?;
    if min.lat >= max.lat || min.lon >= max.lon {
        return Err(format!(
            "empty box `{s}`: the minimum must be below the maximum (minlon,minlat,maxlon,maxlat)"
        ));
    }
    Ok(Clip::BoundingBox { min, max })
}

/// A clip region from a file: GeoJSON (every Polygon and MultiPolygon of a geometry,
/// Feature, FeatureCollection or GeometryCollection, holes included) or Osmosis `.poly`
/// (each ring a polygon; a ring whose name starts with `!` a hole of the polygon that holds
/// it). Told apart by content, not by name.
pub fn read_polygon_file(path: &Path) -> Result<Clip, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read: {e}"))?;
    let polygons = if text.trim_start().starts_with('{') {
        geojson_polygons(&text)?
    } else {
        poly_polygons(&text)?
    };
    if polygons.is_empty() {
        return Err("no polygon in the file".into());
    }
    for polygon in &polygons {
        for ring in std::iter::once(&polygon.outer).chain(&polygon.holes) {
            if ring.len() < 3 {
                return Err("a ring has fewer than three corners".into());
            }
            for p in ring {
                check_lat_lon(*p)?;
            }
        }
    }
    Ok(Clip::Polygons { polygons })
}

fn geojson_polygons(text: &str) -> Result<Vec<ClipPolygon>, String> {
    let gj: geojson::GeoJson = text.parse().map_err(|e| format!("invalid GeoJSON: {e}"))?;
    let mut out = Vec::new();
    match gj {
        geojson::GeoJson::FeatureCollection(fc) => {
            for f in fc.features.iter().filter_map(|f| f.geometry.as_ref()) {
                collect_polygons(&f.value, &mut out);
            }
        }
        geojson::GeoJson::Feature(f) => {
            if let Some(g) = &f.geometry {
                collect_polygons(&g.value, &mut out);
            }
        }
        geojson::GeoJson::Geometry(g) => collect_polygons(&g.value, &mut out),
    }
    if out.is_empty() {
        return Err("no Polygon or MultiPolygon in the GeoJSON".into());
    }
    Ok(out)
}

fn collect_polygons(value: &geojson::GeometryValue, out: &mut Vec<ClipPolygon>) {
    let ring = |r: &[geojson::Position]| -> Vec<LatLon> {
        r.iter()
            .filter_map(|pos| match pos.as_slice() {
                [lon, lat, ..] => Some(LatLon::new(*lat, *lon)),
                _ => None,
            })
            .collect()
    };
    let polygon = |rings: &[Vec<geojson::Position>]| -> Option<ClipPolygon> {
        let (outer, holes) = rings.split_first()?;
        Some(ClipPolygon {
            outer: ring(outer),
            holes: holes.iter().map(|h| ring(h)).collect(),
        })
    };
    match value {
        geojson::GeometryValue::Polygon { coordinates } => out.extend(polygon(coordinates)),
        geojson::GeometryValue::MultiPolygon { coordinates } => {
            out.extend(coordinates.iter().filter_map(|p| polygon(p)));
        }
        geojson::GeometryValue::GeometryCollection { geometries } => {
            for g in geometries {
                collect_polygons(&g.value, out);
            }
        }
        _ => {}
    }
}

/// Osmosis polygon format: a name line, then sections (a name line, `lon lat` lines, `END`;
/// a name starting with `!` is a hole), then `END`. Each hole belongs to the polygon whose
/// outer ring holds its first corner; a hole outside every outer ring is left out.
fn poly_polygons(text: &str) -> Result<Vec<ClipPolygon>, String> {
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    lines.next().ok_or("empty .poly file")?;
    let mut polygons: Vec<ClipPolygon> = Vec::new();
    let mut holes: Vec<Vec<LatLon>> = Vec::new();
    while let Some(section) = lines.next() {
        if section == "END" {
            break;
        }
        let mut ring = Vec::new();
        for line in lines.by_ref() {
            if line == "END" {
                break;
            }
            let mut numbers = line.split_whitespace().map(str::parse::<f64>);
            match (numbers.next(), numbers.next()) {
                (Some(Ok(lon)), Some(Ok(lat))) => ring.push(LatLon::new(lat, lon)),
                _ => return Err(format!("bad .poly line `{line}` (expected `lon lat`)")),
            }
        }
        if section.starts_with('!') {
            holes.push(ring);
        } else {
            polygons.push(ClipPolygon {
                outer: ring,
                holes: Vec::new(),
            });
        }
    }
    if polygons.is_empty() {
        return Err("no outer ring in the .poly file".into());
    }
    for hole in holes {
        let Some(&corner) = hole.first() else {
            continue;
        };
        let owner = polygons
            .iter()
            .position(|p| Clip::polygon(p.outer.clone()).contains(corner));
        // A hole outside every outer ring cuts nothing away.
        if let Some(i) = owner {
            polygons[i].holes.push(hole);
        }
    }
    Ok(polygons)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_and_boxes() -> Result<(), String> {
        assert_eq!(parse_pair(" 1.5, -2 ")?, (1.5, -2.0));
        assert!(
            parse_pair("1").is_err() && parse_pair("1,2,3").is_err() && parse_pair("a,1").is_err()
        );
        assert!(parse_pair("NaN,1").is_err());
        assert_eq!(parse_lat_lon("42.05,-87.67")?, LatLon::new(42.05, -87.67));
        assert!(parse_lat_lon("91,0").is_err());
        assert_eq!(
            parse_bbox("-87.69,42.05,-87.66,42.07")?,
            Clip::BoundingBox {
                min: LatLon::new(42.05, -87.69),
                max: LatLon::new(42.07, -87.66)
            }
        );
        assert!(parse_bbox("-87.66,42.05,-87.69,42.07").is_err());
        assert!(parse_bbox("1,2,3").is_err());
        Ok(())
    }

    #[test]
    fn polygon_files() -> Result<(), String> {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let poly = dir.path().join("campus.poly");
        std::fs::write(&poly, "campus\n1\n  -87.69 42.05\n -87.66 42.05\n -87.66 42.07\nEND\n!2\n0 0\n1 1\n2 0\nEND\nEND\n")
            .map_err(|e| e.to_string())?;
        let Clip::Polygons { polygons } = read_polygon_file(&poly)? else {
            return Err("not a polygon".into());
        };
        assert_eq!(polygons.len(), 1);
        assert_eq!(polygons[0].outer.len(), 3);
        assert_eq!(polygons[0].outer[0], LatLon::new(42.05, -87.69));
        let gj = dir.path().join("campus.geojson");
        std::fs::write(
            &gj,
            r#"{"type":"FeatureCollection","features":[{"type":"Feature","properties":{},"geometry":{"type":"Polygon","coordinates":[[[-87.69,42.05],[-87.66,42.05],[-87.66,42.07],[-87.69,42.05]]]}}]}"#,
        )
        .map_err(|e| e.to_string())?;
        let Clip::Polygons { polygons } = read_polygon_file(&gj)? else {
            return Err("not a polygon".into());
        };
        assert_eq!(polygons[0].outer.len(), 4);
        std::fs::write(&gj, r#"{"type":"Point","coordinates":[0,0]}"#)
            .map_err(|e| e.to_string())?;
        assert!(read_polygon_file(&gj).is_err());
        Ok(())
    }

    #[test]
    fn holes_and_multipolygons_are_kept() -> Result<(), String> {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        // Two squares; the first with a hole in its middle.
        let gj = dir.path().join("area.geojson");
        std::fs::write(
            &gj,
            r#"{"type":"Feature","properties":{},"geometry":{"type":"MultiPolygon","coordinates":[
                [[[0,0],[4,0],[4,4],[0,4],[0,0]],[[1,1],[3,1],[3,3],[1,3],[1,1]]],
                [[[10,0],[12,0],[12,2],[10,2],[10,0]]]]}}"#,
        )
        .map_err(|e| e.to_string())?;
        let poly = dir.path().join("area.poly");
        std::fs::write(
            &poly,
            "area\n1\n0 0\n4 0\n4 4\n0 4\nEND\n2\n10 0\n12 0\n12 2\n10 2\nEND\n!3\n1 1\n3 1\n3 3\n1 3\nEND\nEND\n",
        )
        .map_err(|e| e.to_string())?;
        for file in [&gj, &poly] {
            let clip = read_polygon_file(file)?;
            let region = clip.region();
            let at = |lon: f64, lat: f64| region.contains(LatLon::new(lat, lon));
            assert!(at(0.5, 0.5), "{}: in the first square", file.display());
            assert!(!at(2.0, 2.0), "{}: in the hole", file.display());
            assert!(at(11.0, 1.0), "{}: in the second square", file.display());
            assert!(!at(7.0, 1.0), "{}: between them", file.display());
        }
        let orphan = dir.path().join("orphan.poly");
        std::fs::write(
            &orphan,
            "x\n1\n0 0\n1 0\n1 1\nEND\n!2\n5 5\n6 5\n6 6\nEND\nEND\n",
        )
        .map_err(|e| e.to_string())?;
        let Clip::Polygons { polygons } = read_polygon_file(&orphan)? else {
            return Err("not a polygon".into());
        };
        assert!(polygons[0].holes.is_empty());
        Ok(())
    }
}

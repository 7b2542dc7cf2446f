//! Parsing of the import's geographic options: `--clip-bbox`, `--clip-polygon` files
//! (GeoJSON or Osmosis `.poly`), `--origin`, and `x,y` pairs.

use std::path::Path;

use maps::LatLon;
use maps::build::Clip;

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

/// A clip polygon from a file: GeoJSON (a Polygon or MultiPolygon geometry, Feature or
/// FeatureCollection; the first polygon's outer ring) or Osmosis `.poly` (the first ring
/// that is not a hole). Told apart by content, not by name.
pub fn read_polygon_file(path: &Path) -> Result<Clip, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read: {e}"))?;
    let ring = if text.trim_start().starts_with('{') {
        geojson_ring(&text)?
    } else {
        poly_ring(&text)?
    };
    if ring.len() < 3 {
        return Err("the polygon has fewer than three corners".into());
    }
    for p in &ring {
        check_lat_lon(*p)?;
    }
    Ok(Clip::Polygon { ring })
}

fn geojson_ring(text: &str) -> Result<Vec<LatLon>, String> {
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| format!("invalid GeoJSON: {e}"))?;
    let ring = find_outer_ring(&value).ok_or("no Polygon or MultiPolygon in the GeoJSON")?;
    ring.iter()
        .map(|pos| match pos.as_array().map(Vec::as_slice) {
            Some([lon, lat, ..]) => match (lon.as_f64(), lat.as_f64()) {
                (Some(lon), Some(lat)) => Ok(LatLon::new(lat, lon)),
                _ => Err("a GeoJSON position is not numbers".to_owned()),
            },
            _ => Err("a GeoJSON position is not [lon, lat]".to_owned()),
        })
        .collect()
}

fn find_outer_ring(v: &serde_json::Value) -> Option<&Vec<serde_json::Value>> {
    match v.get("type")?.as_str()? {
        "FeatureCollection" => v
            .get("features")?
            .as_array()?
            .iter()
            .find_map(find_outer_ring),
        "Feature" => find_outer_ring(v.get("geometry")?),
        "Polygon" => v.get("coordinates")?.get(0)?.as_array(),
        "MultiPolygon" => v.get("coordinates")?.get(0)?.get(0)?.as_array(),
        "GeometryCollection" => v
            .get("geometries")?
            .as_array()?
            .iter()
            .find_map(find_outer_ring),
        _ => None,
    }
}

/// Osmosis polygon format: a name line, then sections (a name line, `lon lat` lines, `END`;
/// a name starting with `!` is a hole), then `END`.
fn poly_ring(text: &str) -> Result<Vec<LatLon>, String> {
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    lines.next().ok_or("empty .poly file")?;
    while let Some(section) = lines.next() {
        if section == "END" {
            break;
        }
        let hole = section.starts_with('!');
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
        if !hole {
            return Ok(ring);
        }
    }
    Err("no outer ring in the .poly file".into())
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
        let Clip::Polygon { ring } = read_polygon_file(&poly)? else {
            return Err("not a polygon".into());
        };
        assert_eq!(ring.len(), 3);
        assert_eq!(ring[0], LatLon::new(42.05, -87.69));
        let gj = dir.path().join("campus.geojson");
        std::fs::write(
            &gj,
            r#"{"type":"FeatureCollection","features":[{"type":"Feature","properties":{},"geometry":{"type":"Polygon","coordinates":[[[-87.69,42.05],[-87.66,42.05],[-87.66,42.07],[-87.69,42.05]]]}}]}"#,
        )
        .map_err(|e| e.to_string())?;
        let Clip::Polygon { ring } = read_polygon_file(&gj)? else {
            return Err("not a polygon".into());
        };
        assert_eq!(ring.len(), 4);
        std::fs::write(&gj, r#"{"type":"Point","coordinates":[0,0]}"#)
            .map_err(|e| e.to_string())?;
        assert!(read_polygon_file(&gj).is_err());
        Ok(())
    }
}

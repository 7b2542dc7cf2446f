//! Small OSM XML maps built in code, for tests and examples.

/// A one-way ring of radius 25 m with `ring_tags`, two lanes wide, and three two-way
/// arms 100 m long, as OSM XML.
pub fn two_lane_ring(ring_tags: &str) -> String {
    let n = 12;
    let to_deg = |x: f64, y: f64| {
        (
            50.0 + y / 111_320.0,
            10.0 + x / (111_320.0 * 50f64.to_radians().cos()),
        )
    };
    let mut xml = String::from("<osm version=\"0.6\">\n");
    let mut ring = String::new();
    for i in 0..n {
        let a = std::f64::consts::TAU * f64::from(i) / f64::from(n);
        let (lat, lon) = to_deg(25.0 * a.cos(), 25.0 * a.sin());
        xml += &format!(
            "<node id=\"{}\" lat=\"{lat:.7}\" lon=\"{lon:.7}\"/>\n",
            i + 1
        );
        if i % 4 == 0 {
            let (lat, lon) = to_deg(125.0 * a.cos(), 125.0 * a.sin());
            xml += &format!(
                "<node id=\"{}\" lat=\"{lat:.7}\" lon=\"{lon:.7}\"/>\n\
                 <way id=\"{}\"><nd ref=\"{}\"/><nd ref=\"{}\"/>\
                 <tag k=\"highway\" v=\"residential\"/><tag k=\"lanes\" v=\"4\"/></way>\n",
                100 + i,
                200 + i,
                i + 1,
                100 + i
            );
        }
    }
    for i in 0..=n {
        ring += &format!("<nd ref=\"{}\"/>", i % n + 1);
    }
    xml + &format!(
        "<way id=\"1\">{ring}<tag k=\"highway\" v=\"residential\"/><tag k=\"oneway\" v=\"yes\"/>\
         <tag k=\"lanes\" v=\"2\"/>{ring_tags}</way>\n</osm>\n"
    )
}

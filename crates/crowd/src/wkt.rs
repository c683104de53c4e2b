//! Walkable areas given as WKT, as JuPedSim and PedPy write them: `area = "POLYGON (...)"` or
//! `[area] wkt_file = "room.wkt"` in a scene file, read into the rings of an [`Area`].
//!
//! Reading a scene is two steps: serde takes the area as written (rings, a WKT string, or a
//! file name: [`Area`]'s `Deserialize`), then [`Area::read_wkt`] reads the WKT into `outer` and
//! `holes` (errors name `area` or `area.wkt_file`, the value and why). From then on the area is
//! the same value as one given by its rings: it is validated, written back by
//! [`Scene::to_toml`](crate::Scene::to_toml) and hashed as rings.

use std::path::Path;
use std::str::FromStr;

use ::wkt::Wkt;
use ::wkt::types::Dimension;
use serde::Deserialize;
use serde::de::{self, Deserializer, MapAccess, Visitor};

use crate::error::CrowdError;
use crate::scene::Area;

/// An area the scene file gave as WKT, kept from parsing until [`Area::read_wkt`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum WktSource {
    /// `area = "POLYGON (...)"`.
    Text(String),
    /// `[area] wkt_file = "..."`: a file holding the WKT, relative to the scene file's
    /// directory.
    File(String),
}

/// The `[area]` table as written: the rings, or the WKT file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AreaTable {
    outer: Option<Vec<[f64; 2]>>,
    holes: Option<Vec<Vec<[f64; 2]>>>,
    wkt_file: Option<String>,
}

impl<'de> Deserialize<'de> for Area {
    /// `[area] outer = ..., holes = ...`, `area = "POLYGON (...)"` or `[area] wkt_file = ...`;
    /// the last two still to be read by [`Area::read_wkt`].
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct AreaVisitor;
        impl<'de> Visitor<'de> for AreaVisitor {
            type Value = Area;

            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(
                    "a table with `outer` (and `holes`) or with `wkt_file`, or a WKT string \
                     such as \"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))\"",
                )
            }

            fn visit_str<E: de::Error>(self, text: &str) -> Result<Area, E> {
                Ok(Area::unread(WktSource::Text(text.to_owned())))
            }

            fn visit_map<M: MapAccess<'de>>(self, map: M) -> Result<Area, M::Error> {
                let table = AreaTable::deserialize(de::value::MapAccessDeserializer::new(map))?;
                match table {
                    AreaTable {
                        outer: Some(outer),
                        holes,
                        wkt_file: None,
                    } => Ok(Area {
                        outer,
                        holes: holes.unwrap_or_default(),
                        wkt_source: None,
                    }),
                    AreaTable {
                        outer: None,
                        holes: None,
                        wkt_file: Some(file),
                    } => Ok(Area::unread(WktSource::File(file))),
                    AreaTable {
                        wkt_file: Some(_), ..
                    } => Err(de::Error::custom(
                        "give either `outer` (and `holes`) or `wkt_file`, not both: the WKT \
                         holds the holes",
                    )),
                    AreaTable { outer: None, .. } => Err(de::Error::missing_field("outer")),
                }
            }
        }
        deserializer.deserialize_any(AreaVisitor)
    }
}

impl Area {
    fn unread(source: WktSource) -> Self {
        Area {
            outer: Vec::new(),
            holes: Vec::new(),
            wkt_source: Some(source),
        }
    }

    /// Reads the WKT the scene file gave (its text, or its file relative to `dir`) into
    /// `outer` and `holes`; nothing to do for an area given by its rings. Errors name
    /// `area` or `area.wkt_file`, the value and why.
    pub(crate) fn read_wkt(&mut self, dir: &Path) -> Result<(), CrowdError> {
        let Some(source) = self.wkt_source.take() else {
            return Ok(());
        };
        let (outer, holes) = match &source {
            WktSource::Text(text) => polygon_rings(text)
                .map_err(|why| CrowdError::invalid("area", shorten(text), why))?,
            WktSource::File(name) => {
                let path = dir.join(name);
                let text = std::fs::read_to_string(&path).map_err(|e| {
                    CrowdError::invalid(
                        "area.wkt_file",
                        name,
                        format!("cannot read {}: {e}", path.display()),
                    )
                })?;
                // Editors on Windows start UTF-8 files with a byte-order mark (the TOML
                // reader skips it too); WKT readers refused it as "non-ascii word".
                let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
                polygon_rings(text).map_err(|why| {
                    CrowdError::invalid(
                        "area.wkt_file",
                        name,
                        format!("{} holds {}: {why}", path.display(), shorten(text.trim())),
                    )
                })?
            }
        };
        self.outer = outer;
        self.holes = holes;
        Ok(())
    }

    /// An error if the area is WKT not yet read: a scene deserialized by serde alone, not by
    /// [`Scene::from_toml`](crate::Scene::from_toml) or [`Scene::from_file`](crate::Scene::from_file).
    pub(crate) fn check_read(&self) -> Result<(), CrowdError> {
        match &self.wkt_source {
            None => Ok(()),
            Some(WktSource::Text(text)) => Err(CrowdError::invalid(
                "area",
                shorten(text),
                "WKT not read: read scenes with Scene::from_toml or Scene::from_file",
            )),
            Some(WktSource::File(name)) => Err(CrowdError::invalid(
                "area.wkt_file",
                name,
                "WKT not read: read scenes with Scene::from_toml or Scene::from_file",
            )),
        }
    }
}

/// The rings of a polygon: the outer boundary and the holes, without closing vertices.
type Rings = (Vec<[f64; 2]>, Vec<Vec<[f64; 2]>>);

/// The rings of the one polygon `text` holds (a `POLYGON`, or a `MULTIPOLYGON` of one
/// polygon), without their closing vertices; or why not.
fn polygon_rings(text: &str) -> Result<Rings, String> {
    // The parser recurses once per parenthesis: nested deep enough, it would overflow the
    // stack and abort the process.
    let depth = nesting(text);
    if depth > 3 {
        return Err(format!(
            "parentheses nested {depth} deep: a POLYGON nests them 2 deep, a MULTIPOLYGON 3"
        ));
    }
    let geometry = Wkt::<f64>::from_str(text).map_err(|e| format!("not valid WKT: {e}"))?;
    if let Some(rest) = after_geometry(text)
        && !rest.trim().is_empty()
    {
        return Err(format!(
            "not valid WKT: text after the geometry: {}",
            shorten(rest.trim())
        ));
    }
    let polygon = match geometry {
        Wkt::Polygon(p) => p,
        Wkt::MultiPolygon(m) if m.polygons().len() == 1 => {
            m.into_inner().0.pop().expect("one polygon")
        }
        Wkt::MultiPolygon(m) => {
            return Err(format!(
                "a MULTIPOLYGON of {} polygons: the walkable area is one polygon (its \
                 obstacles are holes)",
                m.polygons().len()
            ));
        }
        other => {
            return Err(format!(
                "a {}: the walkable area is a POLYGON (or a MULTIPOLYGON of one polygon)",
                type_name(&other)
            ));
        }
    };
    if polygon.dimension() != Dimension::XY {
        return Err(format!(
            "coordinates with {:?}: the walkable area is plane (x y)",
            polygon.dimension()
        ));
    }
    let mut rings = polygon
        .into_inner()
        .0
        .into_iter()
        .enumerate()
        .map(|(k, ring)| {
            let mut points: Vec<[f64; 2]> = ring.coords().iter().map(|c| [c.x, c.y]).collect();
            // WKT may repeat a point (OGC allows it; scene rings list each vertex once).
            points.dedup();
            match (points.first(), points.last()) {
                (Some(a), Some(b)) if points.len() > 1 && a == b => {
                    points.pop();
                    Ok(points)
                }
                (Some(a), Some(_)) if points.len() == 1 => {
                    Err(format!("ring {k} is the one point ({} {})", a[0], a[1]))
                }
                (Some(a), Some(b)) => Err(format!(
                    "ring {k} ({}) is not closed: it ends at ({} {}), not at its first point \
                 ({} {})",
                    if k == 0 {
                        "the outer boundary"
                    } else {
                        "a hole"
                    },
                    b[0],
                    b[1],
                    a[0],
                    a[1]
                )),
                _ => Err(format!("ring {k} is empty")),
            }
        });
    let outer = rings.next().ok_or_else(|| {
        "an empty POLYGON: the walkable area needs an outer boundary".to_string()
    })??;
    let holes = rings.collect::<Result<_, _>>()?;
    Ok((outer, holes))
}

/// The text after the geometry: after the parenthesis that closes the first one opened
/// (`None` without parentheses, or when they do not close).
fn after_geometry(text: &str) -> Option<&str> {
    let mut depth = 0usize;
    for (i, c) in text.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => {
                depth = depth.checked_sub(1)?;
                if depth == 0 {
                    return Some(&text[i + 1..]);
                }
            }
            _ => {}
        }
    }
    None
}

/// How deep the parentheses of `text` nest.
fn nesting(text: &str) -> usize {
    let (mut depth, mut deepest) = (0usize, 0);
    for c in text.chars() {
        match c {
            '(' => {
                depth += 1;
                deepest = deepest.max(depth);
            }
            ')' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    deepest
}

/// The WKT keyword of a geometry's type.
fn type_name(geometry: &Wkt<f64>) -> &'static str {
    match geometry {
        Wkt::Point(_) => "POINT",
        Wkt::LineString(_) => "LINESTRING",
        Wkt::Polygon(_) => "POLYGON",
        Wkt::MultiPoint(_) => "MULTIPOINT",
        Wkt::MultiLineString(_) => "MULTILINESTRING",
        Wkt::MultiPolygon(_) => "MULTIPOLYGON",
        Wkt::GeometryCollection(_) => "GEOMETRYCOLLECTION",
    }
}

/// `text` for an error message: at most 120 characters, the rest elided.
fn shorten(text: &str) -> String {
    const MAX: usize = 120;
    match text.char_indices().nth(MAX) {
        Some((i, _)) => format!("{}… ({} characters)", &text[..i], text.chars().count()),
        None => text.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_polygon_with_a_hole_reads_to_its_rings_without_closing_vertices() {
        let (outer, holes) =
            polygon_rings("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (4 4, 6 4, 6 6, 4 6, 4 4))")
                .unwrap();
        assert_eq!(outer, [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]);
        assert_eq!(
            holes,
            [vec![[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0]]]
        );
    }

    #[test]
    fn a_multipolygon_of_one_polygon_is_that_polygon() {
        let one = polygon_rings("MULTIPOLYGON (((0 0, 1 0, 1 1, 0 0)))").unwrap();
        assert_eq!(
            one,
            polygon_rings("POLYGON ((0 0, 1 0, 1 1, 0 0))").unwrap()
        );
    }

    #[test]
    fn other_geometries_and_broken_text_say_why() {
        for (text, why) in [
            (
                "MULTIPOLYGON (((0 0, 1 0, 1 1, 0 0)), ((2 2, 3 2, 3 3, 2 2)))",
                "of 2 polygons",
            ),
            ("POINT (1 2)", "a POINT"),
            ("POLYGON Z ((0 0 1, 1 0 1, 1 1 1, 0 0 1))", "XYZ"),
            (
                "POLYGON ((0 0, 1 0, 1 1))",
                "ring 0 (the outer boundary) is not closed",
            ),
            ("POLYGON EMPTY", "an empty POLYGON"),
            (
                "POLYGON ((0 0, 1 0, 1 1, 0 0)) extra",
                "text after the geometry: extra",
            ),
            ("POLYGON ((0 0, 1 0, 1 1, 0 0)", "not valid WKT"),
            ("", "not valid WKT"),
            (
                "GEOMETRYCOLLECTION (POLYGON ((0 0, 1 0, 1 1, 0 0)))",
                "a GEOMETRYCOLLECTION",
            ),
            (
                "GEOMETRYCOLLECTION (MULTIPOLYGON (((0 0, 1 0, 1 1, 0 0))))",
                "parentheses nested 4 deep",
            ),
        ] {
            let err = polygon_rings(text).unwrap_err();
            assert!(err.contains(why), "{text:?}: {err:?} does not say {why:?}");
        }
    }

    #[test]
    fn deep_nesting_is_refused_before_the_parser_recurses_into_it() {
        // Unchecked, each of these overflows the parser's stack and aborts the process.
        for text in [
            "GEOMETRYCOLLECTION (".repeat(100_000),
            format!("POLYGON {}", "(".repeat(1_000_000)),
        ] {
            let err = polygon_rings(&text).unwrap_err();
            assert!(err.contains("parentheses nested"), "{err}");
        }
    }

    #[test]
    fn long_values_are_shortened_in_messages() {
        let long = "x".repeat(500);
        let short = shorten(&long);
        assert!(short.starts_with(&"x".repeat(120)) && short.ends_with("(500 characters)"));
        assert_eq!(shorten("POINT (1 2)"), "POINT (1 2)");
    }
}

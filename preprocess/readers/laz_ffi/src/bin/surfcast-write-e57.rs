//! Writes an E57 file from a text description, with the `e57` crate's
//! writer: the tests' multi-scan files (poses, spherical coordinates,
//! intensity, colour). Usage: surfcast-write-e57 OUT.e57 < SPEC, where SPEC
//! holds, one per line ('#' starts a comment):
//!
//!   scan NAME                       a new scan (Data3D entry)
//!   pose W X Y Z TX TY TZ           its pose: rotation quaternion, translation
//!   fields cartesian|spherical [intensity|floatintensity] [color] [rowcolumn] [invalid]
//!                                   (floatintensity: 32-bit floats without limits)
//!   intensity-limits MIN MAX        the integer intensity's bounds and limits (default 0 65535)
//!   p A B C [I] [R G B] [ROW COL] [STATE]
//!                                   a point: x y z, or range azimuth elevation
//!                                   (radians); then the fields in that order
//!   claim SCAN RECORDS              after the scans: the XML declares RECORDS
//!                                   points for scan SCAN (a lying file)
//!   replace OLD NEW                 after the scans: the XML with the first OLD
//!                                   replaced by NEW (a malformed file)

use std::io::BufRead;

use e57::{ColorLimits, E57Writer, IntensityLimits, Quaternion, Record, RecordDataType, RecordName, RecordValue, Transform,
          Translation};

#[derive(Default)]
struct Scan {
    name: String,
    pose: Option<Transform>,
    spherical: bool,
    intensity: bool,
    float_intensity: bool,
    color: bool,
    row_column: bool,
    invalid: bool,
    intensity_limits: (i64, i64),
    points: Vec<Vec<f64>>,
}

fn numbers(words: &[&str], line: usize) -> Vec<f64> {
    words.iter().map(|w| w.parse::<f64>().unwrap_or_else(|_| panic!("line {}: '{}' is not a number", line, w))).collect()
}

fn prototype(s: &Scan) -> Vec<Record> {
    let double = || RecordDataType::Double { min: None, max: None };
    let integer = |min: i64, max: i64| RecordDataType::Integer { min, max };
    let mut p = Vec::new();
    let names = if s.spherical {
        [RecordName::SphericalRange, RecordName::SphericalAzimuth, RecordName::SphericalElevation]
    } else {
        [RecordName::CartesianX, RecordName::CartesianY, RecordName::CartesianZ]
    };
    for name in names {
        p.push(Record { name, data_type: double() });
    }
    if s.intensity {
        p.push(Record { name: RecordName::Intensity, data_type: integer(s.intensity_limits.0, s.intensity_limits.1) });
    } else if s.float_intensity {
        p.push(Record { name: RecordName::Intensity, data_type: RecordDataType::Single { min: None, max: None } });
    }
    if s.color {
        for name in [RecordName::ColorRed, RecordName::ColorGreen, RecordName::ColorBlue] {
            p.push(Record { name, data_type: integer(0, 255) });
        }
    }
    if s.row_column {
        p.push(Record { name: RecordName::RowIndex, data_type: integer(0, 1 << 30) });
        p.push(Record { name: RecordName::ColumnIndex, data_type: integer(0, 1 << 30) });
    }
    if s.invalid {
        let name = if s.spherical { RecordName::SphericalInvalidState } else { RecordName::CartesianInvalidState };
        p.push(Record { name, data_type: integer(0, 2) });
    }
    p
}

fn main() {
    let out = std::env::args().nth(1).expect("usage: surfcast-write-e57 OUT.e57 < SPEC");
    let mut scans: Vec<Scan> = Vec::new();
    let mut claims: Vec<(usize, u64)> = Vec::new();
    let mut replacements: Vec<(String, String)> = Vec::new();
    for (k, line) in std::io::stdin().lock().lines().enumerate() {
        let line = line.expect("cannot read the spec");
        let words: Vec<&str> = line.split('#').next().unwrap().split_whitespace().collect();
        let Some((&head, rest)) = words.split_first() else { continue };
        let scan = scans.last_mut();
        match head {
            "scan" => scans.push(Scan { name: rest.join(" "), intensity_limits: (0, 65535), ..Default::default() }),
            "pose" => {
                let v = numbers(rest, k + 1);
                assert!(v.len() == 7, "line {}: pose wants 7 numbers", k + 1);
                scan.expect("pose before scan").pose = Some(Transform {
                    rotation: Quaternion { w: v[0], x: v[1], y: v[2], z: v[3] },
                    translation: Translation { x: v[4], y: v[5], z: v[6] },
                });
            }
            "fields" => {
                let s = scan.expect("fields before scan");
                for w in rest {
                    match *w {
                        "cartesian" => s.spherical = false,
                        "spherical" => s.spherical = true,
                        "intensity" => s.intensity = true,
                        "floatintensity" => s.float_intensity = true,
                        "color" => s.color = true,
                        "rowcolumn" => s.row_column = true,
                        "invalid" => s.invalid = true,
                        _ => panic!("line {}: unknown field '{}'", k + 1, w),
                    }
                }
            }
            "intensity-limits" => {
                let v = numbers(rest, k + 1);
                scan.expect("intensity-limits before scan").intensity_limits = (v[0] as i64, v[1] as i64);
            }
            "p" => scan.expect("p before scan").points.push(numbers(rest, k + 1)),
            "claim" => {
                let v = numbers(rest, k + 1);
                claims.push((v[0] as usize, v[1] as u64));
            }
            "replace" => {
                assert!(rest.len() == 2, "line {}: replace wants OLD NEW", k + 1);
                replacements.push((rest[0].to_string(), rest[1].to_string()));
            }
            _ => panic!("line {}: unknown line '{}'", k + 1, head),
        }
    }

    let mut writer = E57Writer::from_file(&out, "surfcast-test").expect("cannot create the file");
    for (n, s) in scans.iter().enumerate() {
        let proto = prototype(s);
        let mut pc = writer.add_pointcloud(&format!("surfcast-test-scan-{}", n), proto.clone()).expect("add_pointcloud");
        pc.set_name(Some(s.name.clone()));
        pc.set_transform(s.pose.clone());
        if s.intensity {
            pc.set_intensity_limits(Some(IntensityLimits {
                intensity_min: Some(RecordValue::Integer(s.intensity_limits.0)),
                intensity_max: Some(RecordValue::Integer(s.intensity_limits.1)),
            }));
        }
        if s.color {
            let (lo, hi) = (Some(RecordValue::Integer(0)), Some(RecordValue::Integer(255)));
            pc.set_color_limits(Some(ColorLimits {
                red_min: lo.clone(),
                red_max: hi.clone(),
                green_min: lo.clone(),
                green_max: hi.clone(),
                blue_min: lo,
                blue_max: hi,
            }));
        }
        for (i, v) in s.points.iter().enumerate() {
            assert!(v.len() == proto.len(), "scan {} point {}: {} values for {} fields", n, i, v.len(), proto.len());
            let values = v
                .iter()
                .zip(&proto)
                .map(|(&x, r)| match r.data_type {
                    RecordDataType::Double { .. } => RecordValue::Double(x),
                    RecordDataType::Single { .. } => RecordValue::Single(x as f32),
                    _ => RecordValue::Integer(x as i64),
                })
                .collect();
            pc.add_point(values).expect("add_point");
        }
        pc.finalize().expect("finalize the scan");
    }
    writer
        .finalize_customized_xml(|xml| {
            let mut xml = xml;
            for &(scan, records) in &claims {
                // The scan's points section: <points type="CompressedVector" ... recordCount="N">.
                let mut at = 0;
                for _ in 0..=scan {
                    at += xml[at..].find("type=\"CompressedVector\"").expect("no such scan") + 1;
                }
                let key = "recordCount=\"";
                let start = at + xml[at..].find(key).unwrap() + key.len();
                let end = start + xml[start..].find('"').unwrap();
                xml.replace_range(start..end, &records.to_string());
            }
            for (old, new) in &replacements {
                xml = xml.replacen(old.as_str(), new, 1);
            }
            Ok(xml)
        })
        .expect("finalize the file");
}

//! Round trips of the fabrication exports: parse what we wrote and compare
//! with `LineSequence::dot`.

use std::collections::BTreeSet;

use micropos::pattern::export::{
    gds_real8_decode, write_gds, write_png_mask, write_svg, ExportLimits, GdsOptions, Layout,
    PngOptions, Region,
};
use micropos::pattern::sequence::LineSequence;

/// A GDSII reader just big enough for our files: walks records, checks
/// their framing, and returns (units, boundaries as point lists, layers).
struct Gds {
    user_per_db: f64,
    m_per_db: f64,
    boundaries: Vec<Vec<(i32, i32)>>,
    layers: BTreeSet<i16>,
    record_order: Vec<u8>,
}

fn read_gds(b: &[u8]) -> Gds {
    let mut g = Gds {
        user_per_db: 0.0,
        m_per_db: 0.0,
        boundaries: Vec::new(),
        layers: BTreeSet::new(),
        record_order: Vec::new(),
    };
    let mut i = 0;
    let mut in_boundary = false;
    while i < b.len() {
        let len = u16::from_be_bytes([b[i], b[i + 1]]) as usize;
        assert!(len >= 4 && len % 2 == 0, "record length {len} at {i}");
        let (rt, dt) = (b[i + 2], b[i + 3]);
        let data = &b[i + 4..i + len];
        if g.record_order.last() != Some(&rt) || rt != 0x08 {
            g.record_order.push(rt);
        }
        match rt {
            0x00 => assert_eq!((dt, data), (0x02, &600u16.to_be_bytes()[..])),
            0x01 | 0x05 => assert_eq!((dt, data.len()), (0x02, 24)),
            0x03 => {
                assert_eq!((dt, data.len()), (0x05, 16));
                g.user_per_db = gds_real8_decode(data[0..8].try_into().unwrap());
                g.m_per_db = gds_real8_decode(data[8..16].try_into().unwrap());
            }
            0x08 => {
                assert!(!in_boundary);
                in_boundary = true;
            }
            0x0D => {
                assert!(in_boundary);
                g.layers.insert(i16::from_be_bytes([data[0], data[1]]));
            }
            0x10 => {
                assert!(in_boundary);
                assert_eq!(dt, 0x03);
                let pts: Vec<(i32, i32)> = data
                    .chunks_exact(8)
                    .map(|c| {
                        (
                            i32::from_be_bytes(c[0..4].try_into().unwrap()),
                            i32::from_be_bytes(c[4..8].try_into().unwrap()),
                        )
                    })
                    .collect();
                g.boundaries.push(pts);
            }
            0x11 => {
                assert!(in_boundary);
                in_boundary = false;
            }
            0x04 => assert_eq!(i + len, b.len(), "ENDLIB must be last"),
            _ => {}
        }
        i += len;
    }
    assert!(!in_boundary);
    g
}

fn layout(bits: u32, period: f64, dot: Option<f64>, region: Region) -> Layout {
    Layout::new(bits, period, dot, Some(region)).unwrap()
}

fn expected_dots(seq: &LineSequence, r: Region) -> BTreeSet<(i64, i64)> {
    (r.r0..r.r1)
        .flat_map(|row| (r.c0..r.c1).map(move |c| (c, row)))
        .filter(|&(c, row)| seq.dot(c, row))
        .collect()
}

#[test]
fn gds_round_trip_matches_the_sequence() {
    let region = Region {
        c0: 0,
        c1: 60,
        r0: 10,
        r1: 45,
    };
    let l = layout(5, 4.0, Some(1.5), region);
    let mut buf = Vec::new();
    let n = write_gds(
        &l,
        &GdsOptions::default(),
        &ExportLimits::default(),
        &mut buf,
    )
    .unwrap();
    let g = read_gds(&buf);
    assert_eq!(g.user_per_db, 1e-3);
    assert_eq!(g.m_per_db, 1e-9);
    assert_eq!(g.layers, BTreeSet::from([1]));
    // HEADER BGNLIB LIBNAME UNITS BGNSTR STRNAME (BOUNDARY…) ENDSTR ENDLIB.
    assert_eq!(&g.record_order[..6], &[0x00, 0x01, 0x02, 0x03, 0x05, 0x06]);
    assert_eq!(&g.record_order[g.record_order.len() - 2..], &[0x07, 0x04]);

    let want = expected_dots(l.sequence(), region);
    assert_eq!(n as usize, want.len());
    assert_eq!(g.boundaries.len(), want.len());
    let mut got = BTreeSet::new();
    for pts in &g.boundaries {
        assert_eq!(pts.len(), 5);
        assert_eq!(pts[0], pts[4], "closed polygon");
        let xs: Vec<i32> = pts.iter().map(|p| p.0).collect();
        let ys: Vec<i32> = pts.iter().map(|p| p.1).collect();
        let (x0, x1) = (*xs.iter().min().unwrap(), *xs.iter().max().unwrap());
        let (y0, y1) = (*ys.iter().min().unwrap(), *ys.iter().max().unwrap());
        assert_eq!((x1 - x0, y1 - y0), (1500, 1500), "1.5 µm dots in nm");
        let (cx, cy) = ((x0 + x1) / 2, (y0 + y1) / 2);
        assert_eq!((cx % 4000, cy % 4000), (0, 0), "centred on the 4 µm grid");
        got.insert((i64::from(cx / 4000), i64::from(cy / 4000)));
    }
    assert_eq!(got, want);
}

#[test]
fn svg_holds_one_rect_per_dot() {
    let region = Region {
        c0: 20,
        c1: 80,
        r0: 0,
        r1: 30,
    };
    let l = layout(6, 9.0, None, region);
    let mut buf = Vec::new();
    let n = write_svg(&l, &ExportLimits::default(), &mut buf).unwrap();
    let svg = String::from_utf8(buf).unwrap();
    let want = expected_dots(l.sequence(), region);
    assert_eq!(n as usize, want.len());
    assert_eq!(svg.matches("<rect ").count(), want.len());
    assert!(
        svg.contains(r#"viewBox="175.5 -4.5 540 270""#),
        "{}",
        &svg[..300]
    );
    assert!(svg.contains(r#"width="0.54mm""#));
    // Every rect sits on a present dot, 4.5 µm wide.
    let mut got = BTreeSet::new();
    for line in svg.lines().filter(|l| l.starts_with("<rect")) {
        let attr = |name: &str| -> f64 {
            let k = line.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
            line[k..k + line[k..].find('"').unwrap()].parse().unwrap()
        };
        assert_eq!(attr("width"), 4.5);
        let (c, r) = ((attr("x") + 2.25) / 9.0, (attr("y") + 2.25) / 9.0);
        assert!((c - c.round()).abs() < 1e-9 && (r - r.round()).abs() < 1e-9);
        got.insert((c.round() as i64, r.round() as i64));
    }
    assert_eq!(got, want);
}

#[test]
fn png_mask_samples_match_dots() {
    let region = Region {
        c0: 0,
        c1: 40,
        r0: 5,
        r1: 35,
    };
    let l = layout(5, 4.0, None, region);
    let s = 2.0; // px per µm: 8 px per period, dot 4 px.
    let mut buf = Vec::new();
    let (w, h) = write_png_mask(
        &l,
        &PngOptions {
            px_per_um: s,
            dots_white: true,
        },
        &ExportLimits::default(),
        &mut buf,
    )
    .unwrap();
    assert_eq!((w, h), (320, 240));
    let img = image::load_from_memory(&buf).unwrap().into_luma8();
    assert_eq!(img.dimensions(), (320, 240));
    assert!(img.pixels().all(|p| p.0[0] == 0 || p.0[0] == 255));
    let (x0, y0, _, _) = l.canvas_um();
    for r in region.r0..region.r1 {
        for c in region.c0..region.c1 {
            // Pixel containing the dot centre, and one in the gap between dots.
            let j = ((c as f64 * 4.0 - x0) * s) as u32;
            let i = ((r as f64 * 4.0 - y0) * s) as u32;
            let centre = img.get_pixel(j, i).0[0];
            assert_eq!(centre == 255, l.sequence().dot(c, r), "dot ({c}, {r})");
            let gap = img.get_pixel(j + 3, i).0[0];
            assert_eq!(gap, 0, "gap right of ({c}, {r})");
        }
    }
    // Inverted polarity.
    let mut buf2 = Vec::new();
    write_png_mask(
        &l,
        &PngOptions {
            px_per_um: s,
            dots_white: false,
        },
        &ExportLimits::default(),
        &mut buf2,
    )
    .unwrap();
    let inv = image::load_from_memory(&buf2).unwrap().into_luma8();
    assert!(img
        .pixels()
        .zip(inv.pixels())
        .all(|(a, b)| a.0[0] == 255 - b.0[0]));
}

#[test]
fn limits_refuse_before_writing() {
    let l = Layout::new(10, 4.0, None, None).unwrap();
    let tight = ExportLimits {
        max_dots: 1000,
        ..ExportLimits::default()
    };
    let mut buf = Vec::new();
    assert!(write_gds(&l, &GdsOptions::default(), &tight, &mut buf).is_err());
    assert!(write_svg(&l, &tight, &mut buf).is_err());
    assert!(buf.is_empty(), "nothing written when refused");
}

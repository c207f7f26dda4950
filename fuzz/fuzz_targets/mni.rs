//! Any text given to the readers of MNI tag point files and MNI transform files gives `Ok` or `Err`, never a panic.
//! Tag: pairs it reads are complete, active and finite, and so are the points of a file of one volume; written by `to_mni_tag` (unless a name has a character the
//! format cannot hold) they read back to the same positions and names. Transform: a file of linear transforms composes
//! to a finite affine map; when that can be inverted, the text written of its pull-back reads back to the same map.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::landmarks::{parse_mni_tag, parse_mni_tag_points, to_mni_tag};
use warpbench_io::mni_xfm::{self, XfmStep};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let name = Path::new("fuzz.tag");
    if let Ok(pairs) = parse_mni_tag(name, &text) {
        for p in &pairs {
            assert!(p.active && p.is_complete(), "{p:?}");
            let coords = p.moving.iter().chain(&p.fixed).flat_map(|q| q.coords());
            assert!(coords.into_iter().all(f64::is_finite), "{p:?}");
        }
        if let Ok(written) = to_mni_tag(name, &pairs) {
            let back = parse_mni_tag(name, &written).unwrap_or_else(|e| panic!("written tags do not read back: {e}"));
            assert_eq!(back, pairs, "written tags read back differently:\n{written}");
        }
    }
    if let Ok(points) = parse_mni_tag_points(name, &text) {
        let coords = points.iter().flat_map(|p| p.position.map(|q| q.coords()).unwrap_or([f64::NAN; 3]));
        assert!(coords.into_iter().all(f64::is_finite), "{points:?}");
    }
    let name = Path::new("fuzz.xfm");
    let Ok(steps) = mni_xfm::parse(name, &text) else { return };
    let mut map = nalgebra::Matrix4::identity();
    for step in &steps {
        match step {
            XfmStep::Linear(m) => map = m * map,
            // A grid names a file (read by `read_field`, not here), a thin-plate spline is refused: nothing to compose.
            XfmStep::Grid { .. } | XfmStep::Other(_) => return,
        }
    }
    let flip = nalgebra::Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0));
    let Some(u) = (flip * map * flip).try_inverse() else { return };
    if !u.iter().all(|x| x.is_finite()) {
        return;
    }
    let Ok(written) = mni_xfm::to_text(name, &u) else { return };
    let back = mni_xfm::parse(name, &written).unwrap_or_else(|e| panic!("written transform does not read back: {e}"));
    let [XfmStep::Linear(m)] = back.as_slice() else { panic!("written transform is not one linear step: {back:?}") };
    // `to_text` inverts the pull-back again: equal to the map within the conditioning of two inversions.
    let scale = map.iter().fold(1.0f64, |a, x| a.max(x.abs()));
    let cond = u.iter().fold(1.0f64, |a, x| a.max(x.abs())) * scale;
    if cond < 1e6 {
        assert!((m - map).abs().max() <= 1e-9 * scale * cond, "{m} written for {map}");
    }
});

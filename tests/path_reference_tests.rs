//! The `path` references the suite keeps and commits (tests/common.rs, `path_reference`): a
//! reference found on disk must be the image `path` renders now, and the committed store holds
//! the references of one identity only (`tools/path-references keep` replaces it whole).

use crate::common::{
    assert_clean, gpu, path_reference_from, reference_identity, render, scene, COMMITTED_REFERENCES, PATH,
};

#[test]
fn a_path_reference_found_on_disk_is_what_path_renders_now() {
    // A small anisotropic cube under a point light: its reference is committed with the others,
    // so in a clean checkout (CI) it comes from tests/data and is checked against a fresh render
    // bit for bit; rendered now (the code changed since), the second render checks determinism,
    // which the key relies on all the same.
    let gpu = gpu();
    let s = scene(
        "[render]\nwidth = 8\nheight = 8\nseed = 3\nspp = 64\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 6.0\nalbedo = 0.9\ng = 0.4\n\
         density = { kind = \"constant\" }\n\
         [[light]]\nkind = \"point\"\nposition = [1.0, 1.0, 1.0]\nintensity = 10.0\n",
    );
    let (reference, source) = path_reference_from(&gpu, &s, &[]);
    let fresh = render(&gpu, &s, PATH, &[]);
    eprintln!("reference {source:?}");
    assert!(fresh.image.data.iter().any(|v| *v > 0.0), "a dark image proves nothing");
    assert!(reference.image.data == fresh.image.data, "the {source:?} reference differs from path's render now");
    assert!(
        reference.variance.as_ref().map(|v| &v.data) == fresh.variance.as_ref().map(|v| &v.data),
        "the {source:?} reference's variance differs from path's render now"
    );
    assert_clean(&gpu);
}

#[test]
fn the_committed_references_share_one_identity() {
    // Identity first, then the scene's key: `<identity>-<key>.exr`. One identity at a time, so
    // a stale set never lingers beside the current one; whether it is this build's is not
    // asserted (a change to the tracer renders them afresh until they are kept again).
    let Ok(entries) = std::fs::read_dir(COMMITTED_REFERENCES) else {
        panic!("{COMMITTED_REFERENCES}: the committed store is missing (tools/path-references keep makes it)")
    };
    let mut identities = std::collections::BTreeSet::new();
    let mut count = 0;
    for e in entries {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        let Some(stem) = name.strip_suffix(".exr") else {
            assert!(name == "README.md", "{COMMITTED_REFERENCES}/{name}: not a reference");
            continue;
        };
        let (identity, key) = stem.split_once('-').unwrap_or_else(|| panic!("{name}: not <identity>-<key>.exr"));
        assert!(identity.len() == 12 && key.len() == 20, "{name}: not <identity>-<key>.exr");
        identities.insert(identity.to_string());
        count += 1;
    }
    assert!(identities.len() <= 1, "{count} references of {} identities: {identities:?}", identities.len());
    let gpu = gpu();
    eprintln!("{count} committed references of {identities:?}; this build's identity {}", reference_identity(&gpu));
}

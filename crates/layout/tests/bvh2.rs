mod common;
use common::*;

#[test]
fn bvh2_matches_brute_force_and_counts_its_bytes() {
    for s in SCENES {
        let c = case(s, 2, 2000, 7);
        let l = check(&c, &spec("bvh2", &[]));
        let m = l.memory();
        assert_eq!(m.topology_bytes, c.bvh.nodes.len() as u64 * 32);
        assert_eq!(
            m.total_bytes,
            m.topology_bytes + 4 * c.scene.triangles.len() as u64
        );
        assert_eq!(m.topology_bits_per_node(), 256.0);
    }
}

#[test]
fn specs_are_validated() {
    use bvhlab_layout::LayoutSpec;
    let raw = |kv: &[(&str, &str)]| {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    };
    assert!(LayoutSpec::parse("bvh3", &raw(&[]))
        .unwrap_err()
        .contains("valid: bvh2"));
    assert!(LayoutSpec::parse("bvh2", &raw(&[("bits", "8")]))
        .unwrap_err()
        .contains("unknown parameter `bits` for layout `bvh2`; valid parameters: (none)"));
    let q = LayoutSpec::parse("qbvh_chunks", &raw(&[])).unwrap();
    assert_eq!(q.params_string(), "bits=8,chunk_bytes=64,frame=chunk");
}

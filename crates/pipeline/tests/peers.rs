//! Peer builders (crates/peers) through the pipeline: cached like any builder, valid trees that
//! find brute force's hits (every layout too), the peer's own traversal agreeing on every ray,
//! the library in the row and in the key, and the stress scenes giving a tree or a clear error.
use bvhlab_peers::Peer;
use bvhlab_pipeline::{ChainSpec, RaySpec, Runner, Store};

fn peers() -> Vec<&'static str> {
    Peer::ALL.iter().filter(|p| p.available().is_ok()).map(|p| p.method().name).collect()
}

#[test]
fn peers_run_as_builders_with_their_own_traversal() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    for scene in ["gen:sphere:n=4000", "gen:city:blocks=8"] {
        for name in peers() {
            let mut c = ChainSpec::new(scene, name);
            c.repeat = 2;
            c.rays = Some(RaySpec::Random { count: 4000 });
            let row = r.run_chain(&c, "t").unwrap();
            assert!(row.valid, "{name} on {scene}: {}", row.method);
            assert!(row.library.is_some(), "{name}");
            assert!(row.build_seconds > 0.0 && row.sah_cost > 1.0, "{name}");
            assert_eq!(row.peer_hit_mismatches, Some(0), "{name} on {scene}");
            assert!(row.peer_mrays_per_s.unwrap() > 0.0);
            // The same chain again comes from the cache.
            let again = r.run_chain(&c, "t").unwrap();
            assert_eq!(again.bvh_hash, row.bvh_hash);
        }
    }
}

/// Every layout of a peer's tree finds the same hits as brute force (the measure stage checks its
/// layout against bvh2; the oracle of bvh2 is bvhlab's exact traversal).
#[test]
fn peer_trees_agree_with_brute_force() {
    let scene = bvhlab_geom::gen::generate("hairball:n=1500").unwrap();
    let tris = &scene.triangles;
    let boxes: Vec<_> = tris.iter().map(|t| t.bounds()).collect();
    let b = scene.bounds();
    let rays = bvhlab_trace::random_rays(&b, b.enclosing_radius(tris.iter().map(|t| t.bounds().center())), 2000, 3);
    let want = bvhlab_trace::brute_force(tris, &rays);
    let reg = bvhlab_pipeline::Registry::standard();
    for name in peers() {
        let r = reg.resolve(name, &Default::default(), Default::default()).unwrap();
        let p = reg.get(name).unwrap().peer.unwrap();
        let built = p.build(tris, &boxes, &r.params, 3.0, 2.0).unwrap();
        let got = bvhlab_trace::trace(&built.bvh, tris, &rays);
        assert!(got.hits == want, "{name}");
    }
}

/// The stress generators: a valid tree or a clear error, never a panic.
#[test]
fn peers_on_stress_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    for scene in ["gen:degenerate", "gen:huge-edge", "gen:outlier:e=20", "gen:scale:s=1e30", "gen:scale:s=1e-30"] {
        for name in peers() {
            let mut c = ChainSpec::new(scene, name);
            c.repeat = 1;
            match r.run_chain(&c, "t") {
                Ok(row) => assert!(row.valid, "{name} on {scene}: {}", row.method),
                Err(e) => assert!(e.message().contains(name), "{name} on {scene}: {e}"),
            }
        }
    }
}

//! Encoders (the encode stage, for builders over sorted codes): one registration line each (the
//! [`Method`](super::Method) comes from `crates/morton/src/`).
use super::{MethodInfo, MethodKind};
use bvhlab_morton::{emc, morton, Scheme};

/// What the pipeline needs to run an encoder.
#[derive(Clone)]
pub struct Encoder {
    pub scheme: Scheme,
}

impl MethodKind for Encoder {
    const WHAT: &'static str = "encoder";
}

pub type EncoderInfo = MethodInfo<Encoder>;

/// The standard encoders: one line each (the order of `bvhlab methods`).
#[rustfmt::skip]
pub fn standard() -> Vec<EncoderInfo> {
    vec![
        encoder(&morton::METHOD, Scheme::Morton),
        encoder(&emc::EMC64_SORT, Scheme::Emc64Sort),
        encoder(&emc::EMC64_VAR, Scheme::Emc64Var),
    ]
}

fn encoder(m: &super::Method, scheme: Scheme) -> EncoderInfo {
    MethodInfo::new(m, Encoder { scheme })
}

#[cfg(test)]
mod tests {
    use crate::registry::tests::raw;
    use crate::registry::Registry;
    use bvhlab_bvh::CostParams;
    use bvhlab_morton::{AutoFor, Bits, BoundsMode, CellFrame};

    #[test]
    fn encoder_routing_and_auto_bits() {
        let r = Registry::standard();
        let c = CostParams::default();
        let (b, e) = r
            .resolve_chain(
                "ploc",
                None,
                None,
                &raw(&[("radius", "25"), ("bounds", "concise")]),
                c,
            )
            .unwrap()
            .parts();
        let e = e.unwrap();
        assert_eq!(crate::key::params_string(&b.params), "radius=25");
        assert_eq!(e.encoder, "morton");
        assert_eq!(
            crate::key::params_string(&e.params),
            "bits=auto:ploc,bounds=concise,grid_bits=0"
        );
        assert_eq!(e.config.bits, Bits::Auto(AutoFor::Ploc));
        assert_eq!(e.config.bounds, BoundsMode::Concise);
        assert_eq!(r.encoder_label(&e), "morton bounds=concise");
        let (_, e) = r
            .resolve_chain("aac", Some("morton"), None, &raw(&[("bits", "auto")]), c)
            .unwrap()
            .parts();
        assert_eq!(e.as_ref().unwrap().params["bits"], "auto:aac");
        // The encoder an lbvh chain resolves with these parameters.
        let lbvh = |encoder: &str, kv: &[(&str, &str)]| {
            r.resolve_chain("lbvh", Some(encoder), None, &raw(kv), c).unwrap().parts().1.unwrap()
        };
        let e = lbvh("morton", &[("bits", "10"), ("grid_bits", "9")]);
        assert_eq!((e.config.bits, e.config.grid_bits), (Bits::Fixed(10), 9));
        assert_eq!(r.encoder_label(&e), "morton bits=10 grid_bits=9");
        assert_eq!(e.cell_frame, CellFrame::Lattice);
        let t = lbvh("emc64-var", &[("grid_bits", "9"), ("grid_frame", "tight")]);
        assert_eq!(
            (t.cell_frame, r.encoder_label(&t).as_str()),
            (CellFrame::Tight, "emc64-var grid_bits=9 grid_frame=tight")
        );
        assert_eq!(
            crate::key::params_string(&t.params),
            "bounds=scene,grid_bits=9,grid_frame=tight"
        );
        let err = r
            .resolve_chain(
                "lbvh",
                Some("morton"),
                None,
                &raw(&[("grid_frame", "tight")]),
                c,
            )
            .unwrap_err();
        assert!(
            err.message().contains("grid_bits") && err.exit_code() == 2,
            "{err}"
        );
        // EMC encoders have no bits; their key does not depend on the builder.
        let (_, a) = r
            .resolve_chain("aac", Some("emc64-var"), None, &raw(&[]), c)
            .unwrap()
            .parts();
        let (_, p) = r
            .resolve_chain("ploc", Some("emc64-var"), None, &raw(&[]), c)
            .unwrap()
            .parts();
        assert_eq!(a.as_ref().unwrap().params, p.as_ref().unwrap().params);
        assert_eq!(a.unwrap().config, p.unwrap().config);
        // Top-down builders have no encoder.
        assert_eq!(
            r.resolve_chain("binned-sah", None, None, &raw(&[]), c)
                .unwrap()
                .encoder,
            None
        );
    }

    #[test]
    fn encoder_errors() {
        let r = Registry::standard();
        let c = CostParams::default();
        let e = r
            .resolve_chain("ploc", Some("emc64-var"), None, &raw(&[("bits", "10")]), c)
            .unwrap_err();
        assert!(
            e.message().contains("`bits`") && e.message().contains("bounds, grid_bits"),
            "{e}"
        );
        let e = r
            .resolve_chain("sweep-sah", Some("morton"), None, &raw(&[]), c)
            .unwrap_err();
        assert!(
            e.message().contains("top-down") && e.message().contains("lbvh, aac, ploc"),
            "{e}"
        );
        let e = r
            .resolve_chain("sweep-sah", None, None, &raw(&[("bounds", "scene")]), c)
            .unwrap_err();
        assert!(e.message().contains("encoder parameter"), "{e}");
        let e = r
            .resolve_chain("lbvh", Some("hilbert"), None, &raw(&[]), c)
            .unwrap_err();
        assert!(
            e.message().contains("emc64-sort") && e.exit_code() == 2,
            "{e}"
        );
        for (k, v) in [
            ("bits", "0"),
            ("bits", "22"),
            ("bits", "auto:ploc"),
            ("bounds", "box"),
            ("grid_bits", "7"),
        ] {
            let e = r
                .resolve_chain("aac", None, None, &raw(&[(k, v)]), c)
                .unwrap_err();
            assert!(
                e.message().contains(k) && e.exit_code() == 2,
                "{k}={v}: {e}"
            );
        }
    }
}

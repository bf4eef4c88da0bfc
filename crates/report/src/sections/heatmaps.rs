//! Heat maps as a thumbnail gallery grouped by scene, each with its colour scale; a click opens
//! the full image.
use super::{section, Heatmap};
use crate::html::href;
use maud::{html, Markup};

pub fn gallery(maps: &[Heatmap]) -> Markup {
    let max = bvhlab_pipeline::HEAT_MAX_STEPS;
    let mut scenes: Vec<&str> = Vec::new();
    for m in maps {
        if !scenes.contains(&m.scene.as_str()) {
            scenes.push(&m.scene);
        }
    }
    let body = html! {
        @if maps.is_empty() {
            p { "No heat maps (they come with primary ray sets)." }
        } @else {
            p { "Traversal steps per primary ray, blue (0) to red (" (max) " or more); click a thumbnail for the full image." }
            @for s in &scenes {
                h3 { (s) }
                div.gallery {
                    @for m in maps.iter().filter(|m| m.scene == *s) {
                        figure.thumb {
                            a href=(href(&m.file)) { img src=(href(&m.file)) alt=(m.caption) loading="lazy"; }
                            div.scale title={ "0 to " (max) "+ steps" } {}
                            div.scale-labels { span { "0" } span { (max / 2) } span { (max) "+" } }
                            figcaption { (m.caption) }
                        }
                    }
                }
            }
        }
    };
    section("heatmaps", &format!("Heat maps ({})", maps.len()), false, body)
}

//! What the workbench carries in its binary from `assets/`: the window icon and the trainer
//! notes of the shipped scenarios.

use std::collections::BTreeMap;
use std::sync::OnceLock;

use eframe::egui;

/// The application icon (256×256 RGBA PNG), shown by the window and the task bar.
const ICON_PNG: &[u8] = include_bytes!("../../assets/icon.png");

/// Trainer notes, one per shipped preset file name (RON map).
const SCENARIOS_RON: &str = include_str!("../../assets/scenarios.ron");

/// The icon decoded for the window; None if the embedded PNG does not decode (a build
/// defect the tests catch; the window then opens with the platform's default icon).
pub fn icon() -> Option<egui::IconData> {
    let img = image::load_from_memory_with_format(ICON_PNG, image::ImageFormat::Png)
        .ok()?
        .into_rgba8();
    let (width, height) = img.dimensions();
    Some(egui::IconData {
        rgba: img.into_raw(),
        width,
        height,
    })
}

fn notes() -> &'static BTreeMap<String, String> {
    static NOTES: OnceLock<BTreeMap<String, String>> = OnceLock::new();
    NOTES.get_or_init(|| ron::from_str(SCENARIOS_RON).unwrap_or_default())
}

/// The trainer note for shipped preset `name` ("" when it has none).
pub fn scenario_note(name: &str) -> &'static str {
    notes().get(name).map_or("", String::as_str)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_icon_decodes_and_every_shipped_preset_has_a_note() {
        let icon = icon().expect("icon.png decodes");
        assert_eq!((icon.width, icon.height), (256, 256));
        assert_eq!(icon.rgba.len(), 256 * 256 * 4);
        let parsed: BTreeMap<String, String> =
            ron::from_str(SCENARIOS_RON).expect("scenarios.ron parses");
        for name in axisbench::preset::SHIPPED_PRESETS {
            assert!(
                parsed.get(*name).is_some_and(|n| n.len() > 40),
                "no trainer note for {name}"
            );
        }
    }
}

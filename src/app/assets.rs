//! What the workbench carries in its binary from `assets/`: the window icon and the trainer
//! notes of the shipped scenarios.

use std::collections::BTreeMap;
use std::sync::OnceLock;

use eframe::egui;

/// The application icon (256×256 RGBA PNG), shown by the window and the task bar.
const ICON_PNG: &[u8] = include_bytes!("../../assets/icon.png");

/// The shipped scenarios' notes and views, by preset file name (RON map).
const SCENARIOS_RON: &str = include_str!("../../assets/scenarios.ron");

/// How the workbench opens a shipped scenario.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioView {
    /// The trainer note.
    pub note: String,
    /// Machine time per wall time.
    pub speed: f64,
    /// The rolling window, s.
    pub window_s: f64,
    /// Whether the time plots show the whole run.
    pub whole_run: bool,
}

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

fn views() -> &'static BTreeMap<String, ScenarioView> {
    static VIEWS: OnceLock<BTreeMap<String, ScenarioView>> = OnceLock::new();
    VIEWS.get_or_init(|| ron::from_str(SCENARIOS_RON).unwrap_or_default())
}

/// How shipped preset `name` opens (None for a preset that is not shipped).
pub fn scenario(name: &str) -> Option<&'static ScenarioView> {
    views().get(name)
}

/// The trainer note for shipped preset `name` ("" when it has none).
pub fn scenario_note(name: &str) -> &'static str {
    scenario(name).map_or("", |v| v.note.as_str())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_icon_decodes_and_every_shipped_preset_has_a_note() {
        let icon = icon().expect("icon.png decodes");
        assert_eq!((icon.width, icon.height), (256, 256));
        assert_eq!(icon.rgba.len(), 256 * 256 * 4);
        let parsed: BTreeMap<String, ScenarioView> =
            ron::from_str(SCENARIOS_RON).expect("scenarios.ron parses");
        for name in axisbench::preset::SHIPPED_PRESETS {
            let v = parsed.get(*name).expect("every shipped preset has a view");
            assert!(v.note.len() > 40, "no trainer note for {name}");
            assert!(
                (0.1..=1000.0).contains(&v.speed),
                "{name}: speed off the slider"
            );
            assert!(
                (1.0..=super::super::live::MAX_WINDOW_S).contains(&v.window_s),
                "{name}: window off the slider"
            );
        }
    }
}

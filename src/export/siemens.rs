//! placeholder
use super::{Ctx, Rendered, Violation};
pub(crate) fn render(_ctx: &Ctx) -> Result<Rendered, Vec<Violation>> {
    Err(vec![Violation::new("siemens", "not yet")])
}

//! Where the four panels sit in the image.

/// A panel's pixel rectangle in the output image: `x0..x1`, `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PanelRect {
    /// Left edge (inclusive).
    pub x0: u32,
    /// Top edge (inclusive).
    pub y0: u32,
    /// Right edge (exclusive).
    pub x1: u32,
    /// Bottom edge (exclusive).
    pub y1: u32,
}

/// Height of the title strip (px).
const TITLE_PX: u32 = 36;

/// The four panels' rectangles for an image of this size: force, solver effort, top view, side view.
pub fn panel_layout(width_px: u32, height_px: u32) -> [PanelRect; 4] {
    let body = height_px - TITLE_PX;
    let row1 = TITLE_PX + body * 3 / 10;
    let row2 = row1 + body * 3 / 10;
    let half = width_px / 2;
    [
        PanelRect {
            x0: 0,
            y0: TITLE_PX,
            x1: width_px,
            y1: row1,
        },
        PanelRect {
            x0: 0,
            y0: row1,
            x1: width_px,
            y1: row2,
        },
        PanelRect {
            x0: 0,
            y0: row2,
            x1: half,
            y1: height_px,
        },
        PanelRect {
            x0: half,
            y0: row2,
            x1: width_px,
            y1: height_px,
        },
    ]
}

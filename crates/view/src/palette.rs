//! The scene palette: the colours of the probe, proxy, hand target, force, volume bounds, haptic modes
//! and force plot axes. Defined once, as the `--scene-*` CSS variables at the top of web/style.css; the
//! built-in page reads them in app.js, and voxhap reads the same lines here (from the embedded stylesheet)
//! for the Foxglove scene and the layout file's plot colours, so the page and Foxglove always agree.
//!
//! Where it sits: the Foxglove messages (`super::foxglove::messages`, `crate::topics`) ask
//! [`palette`] for colours; the stylesheet is parsed once, on first use.

/// The page's stylesheet, where the scene colours are defined (`--scene-*` variables).
const STYLE_CSS: &str = include_str!("../../../web/style.css");
use std::sync::OnceLock;

/// An sRGB colour, components in 0 ..= 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rgb {
    pub r: f64,
    pub g: f64,
    pub b: f64,
}

impl Rgb {
    /// `#rrggbb`.
    pub fn hex(&self) -> String {
        let byte = |v: f64| (v * 255.0).round().clamp(0.0, 255.0) as u8;
        format!(
            "#{:02x}{:02x}{:02x}",
            byte(self.r),
            byte(self.g),
            byte(self.b)
        )
    }
}

/// Every scene colour.
#[derive(Debug, Clone, PartialEq)]
pub struct Palette {
    pub probe: Rgb,
    pub proxy: Rgb,
    pub hand: Rgb,
    pub force: Rgb,
    pub bounds: Rgb,
    /// Colour of the haptic mode with index `i` (mod 8): its primitives, and for a surface mode its
    /// iso-surface mesh.
    pub modes: [Rgb; 8],
    /// Force plot lines: x, y, z, magnitude.
    pub force_axes: [Rgb; 4],
}

impl Palette {
    /// The colour of mode `index`.
    pub fn mode(&self, index: usize) -> Rgb {
        self.modes[index % self.modes.len()]
    }
}

/// The CSS variable names, in the order [`Palette`] uses them.
#[cfg(test)]
const NAMES: [&str; 17] = [
    "probe",
    "proxy",
    "hand",
    "force",
    "bounds",
    "mode-0",
    "mode-1",
    "mode-2",
    "mode-3",
    "mode-4",
    "mode-5",
    "mode-6",
    "mode-7",
    "force-x",
    "force-y",
    "force-z",
    "force-magnitude",
];

/// Grey, for a variable the stylesheet lacks (a unit test makes sure none is missing).
const MISSING: Rgb = Rgb {
    r: 0.5,
    g: 0.5,
    b: 0.5,
};

fn parse_hex(text: &str) -> Option<Rgb> {
    let hex = text.trim().strip_prefix('#')?;
    if hex.len() != 6 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let channel = |at: usize| {
        u8::from_str_radix(&hex[at..at + 2], 16)
            .ok()
            .map(|v| f64::from(v) / 255.0)
    };
    Some(Rgb {
        r: channel(0)?,
        g: channel(2)?,
        b: channel(4)?,
    })
}

/// The `--scene-NAME: #rrggbb;` declarations of `css`, by NAME.
fn declarations(css: &str) -> Vec<(String, Option<Rgb>)> {
    css.lines()
        .filter_map(|line| {
            let line = line.trim();
            let rest = line.strip_prefix("--scene-")?;
            let (name, value) = rest.split_once(':')?;
            Some((
                name.trim().to_owned(),
                parse_hex(value.trim().trim_end_matches(';')),
            ))
        })
        .collect()
}

fn from_css(css: &str) -> Palette {
    let found = declarations(css);
    let colour = |name: &str| {
        found
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, c)| *c)
            .unwrap_or(MISSING)
    };
    Palette {
        probe: colour("probe"),
        proxy: colour("proxy"),
        hand: colour("hand"),
        force: colour("force"),
        bounds: colour("bounds"),
        modes: std::array::from_fn(|i| colour(&format!("mode-{i}"))),
        force_axes: [
            colour("force-x"),
            colour("force-y"),
            colour("force-z"),
            colour("force-magnitude"),
        ],
    }
}

/// The palette of the embedded web/style.css.
pub fn palette() -> &'static Palette {
    static PALETTE: OnceLock<Palette> = OnceLock::new();
    PALETTE.get_or_init(|| from_css(STYLE_CSS))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stylesheet_defines_every_scene_colour_once_as_rrggbb() {
        let found = declarations(STYLE_CSS);
        for name in NAMES {
            let matches: Vec<_> = found.iter().filter(|(n, _)| n == name).collect();
            assert_eq!(
                matches.len(),
                1,
                "--scene-{name} defined {} times",
                matches.len()
            );
            assert!(matches[0].1.is_some(), "--scene-{name} is not #rrggbb");
        }
        assert_eq!(
            found.len(),
            NAMES.len(),
            "unexpected --scene-* variables: {found:?}"
        );
        let p = palette();
        assert_eq!(p.proxy.hex(), "#ffd23f");
        assert_ne!(p.probe, p.proxy);
        assert!(p.modes.iter().all(|m| *m != MISSING));
    }

    #[test]
    fn the_page_script_takes_its_scene_colours_from_the_stylesheet() {
        let script = include_str!("../../../web/app.js");
        assert!(script.contains("--scene-${name}"));
        let p = from_css(STYLE_CSS);
        for colour in [p.probe, p.proxy, p.hand, p.force] {
            let hex = colour.hex();
            assert!(
                !script.contains(&format!("'{hex}'")),
                "app.js hard-codes {hex}"
            );
        }
        assert_eq!(parse_hex("#zz0000"), None);
        assert_eq!(from_css("").probe, MISSING);
    }
}

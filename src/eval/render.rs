//! Pictures of equivalence classes (as the thesis's Figures 4.6 and 5.1): a mesh ray traced from the automatic
//! camera with every triangle in the colour of its class, Lambert-shaded so that shape stays visible, above a
//! legend: a bar whose segments are the classes' shares of the triangles, and each class's colour swatch with its
//! triangle count in a built-in 3x5 digit font.
//!
//! Colours are exact and decodable: class `c` at shade level `l` is [`shaded`]`(c, l)`, and [`decode_class`]
//! recovers `c` from a pixel, so a test can check that every pixel shows the class of the triangle it hit.

use crate::accel::bvh::Bvh;
use crate::accel::{AccelError, AccelStructure};
use crate::geom::Camera;
use crate::geom::TraceCounters;
use crate::mesh::Mesh;
use crate::trace::workload::mesh_bounds;

/// Shade levels of the Lambert term (level `l` scales a class colour by `0.3 + 0.7 l / (SHADE_LEVELS - 1)`).
pub const SHADE_LEVELS: u32 = 12;

/// Background colour (white, which no class colour takes).
pub const BACKGROUND: [u8; 3] = [255, 255, 255];

/// Legend text and frame colour.
pub const INK: [u8; 3] = [0, 0, 0];

/// Errors of rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The structure could not be built.
    #[error(transparent)]
    Accel(#[from] AccelError),
    /// Arguments that cannot be rendered.
    #[error("{0}")]
    Invalid(String),
    /// Encoding or writing the PNG failed.
    #[error("png: {0}")]
    Png(String),
}

/// The unshaded colour of class `c`: hues a golden angle apart (neighbouring classes, which are neighbours in
/// Morton order and so in space, get contrasting hues), alternating saturation and value.
pub fn class_colour(c: u32) -> [u8; 3] {
    let h = (f64::from(c) * 0.618_033_988_749_895).fract() * 6.0;
    let s = if c % 2 == 0 { 0.85 } else { 0.55 };
    let v = if (c / 2) % 2 == 0 { 1.0 } else { 0.78 };
    let i = h.floor();
    let f = h - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    let (r, g, b) = match i as u32 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r, g, b].map(|x| (x * 255.0).round() as u8)
}

/// Class `c`'s colour at shade level `level` (clamped to `SHADE_LEVELS - 1`).
pub fn shaded(c: u32, level: u32) -> [u8; 3] {
    let l = level.min(SHADE_LEVELS - 1);
    let f = 0.3 + 0.7 * f64::from(l) / f64::from(SHADE_LEVELS - 1);
    class_colour(c).map(|x| (f64::from(x) * f).round() as u8)
}

/// The class `c < classes` with `shaded(c, l) == rgb` for some level `l`, when exactly one class matches.
pub fn decode_class(rgb: [u8; 3], classes: u32) -> Option<u32> {
    let mut found = None;
    for c in 0..classes {
        if (0..SHADE_LEVELS).any(|l| shaded(c, l) == rgb) {
            if found.is_some() {
                return None;
            }
            found = Some(c);
        }
    }
    found
}

/// A rendered picture: the image (render area on top, legend below) and what every render pixel hit.
#[derive(Clone, Debug)]
pub struct ClassImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels (render area plus legend).
    pub height: u32,
    /// Height of the render area (the top `width x render_height` pixels).
    pub render_height: u32,
    /// RGB pixels, row by row, top row first.
    pub pixels: Vec<[u8; 3]>,
    /// The triangle each render-area pixel shows (`None`: background).
    pub triangle: Vec<Option<u32>>,
    /// Number of classes.
    pub classes: u32,
    /// Triangles per class (the legend).
    pub counts: Vec<u64>,
    /// First row of the share bar, and its height.
    pub bar: (u32, u32),
}

impl ClassImage {
    /// The pixel at `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        self.pixels[(y * self.width + x) as usize]
    }

    fn set(&mut self, x: u32, y: u32, c: [u8; 3]) {
        if x < self.width && y < self.height {
            self.pixels[(y * self.width + x) as usize] = c;
        }
    }

    fn fill(&mut self, x0: u32, y0: u32, w: u32, h: u32, c: [u8; 3]) {
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                self.set(x, y, c);
            }
        }
    }

    /// The PNG file of the image (8-bit RGB).
    pub fn encode_png(&self) -> Result<Vec<u8>, RenderError> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Best);
            let mut w = enc.write_header().map_err(|e| RenderError::Png(e.to_string()))?;
            let data: Vec<u8> = self.pixels.iter().flatten().copied().collect();
            w.write_image_data(&data).map_err(|e| RenderError::Png(e.to_string()))?;
        }
        Ok(out)
    }
}

/// 3x5 bitmaps of the digits 0-9, one row per 3 bits (bit 2 = left column).
const DIGITS: [[u8; 5]; 10] = [
    [7, 5, 5, 5, 7],
    [2, 6, 2, 2, 7],
    [7, 1, 7, 4, 7],
    [7, 1, 7, 1, 7],
    [5, 5, 7, 1, 1],
    [7, 4, 7, 1, 7],
    [7, 4, 7, 5, 7],
    [7, 1, 1, 1, 1],
    [7, 5, 7, 5, 7],
    [7, 5, 7, 1, 7],
];

/// Pixel scale of the digit font.
const FONT_SCALE: u32 = 2;
/// Legend layout: bar height, row height, entry width, swatch side.
const BAR_H: u32 = 20;
const ROW_H: u32 = 18;
const ENTRY_W: u32 = 96;
const SWATCH: u32 = 12;

fn draw_number(img: &mut ClassImage, x: u32, y: u32, n: u64) {
    for (i, ch) in n.to_string().bytes().enumerate() {
        let d = usize::from(ch - b'0');
        let x0 = x + i as u32 * 4 * FONT_SCALE;
        for (row, bits) in DIGITS[d].iter().enumerate() {
            for col in 0..3u32 {
                if bits & (4 >> col) != 0 {
                    img.fill(x0 + col * FONT_SCALE, y + row as u32 * FONT_SCALE, FONT_SCALE, FONT_SCALE, INK);
                }
            }
        }
    }
}

/// A camera inside the bounds of `mesh` (for interiors such as an atrium): at the centre, moved back by 45% of the
/// longest horizontal extent and down by 20% of the height, looking along that axis at the far wall, with a 70
/// degree field of view and +y up. `None` for an empty mesh, and where that camera's f32 arithmetic fails: bounds
/// too large (an extent past `f32::MAX`), too thin to look along, or so far from the origin for their size that the
/// eye and the target round to one point.
pub fn interior_camera(mesh: &Mesh) -> Option<Camera> {
    let b = mesh_bounds(mesh);
    if b.is_empty() {
        return None;
    }
    let (c, e) = (b.center(), b.extent());
    let axis = if e.x >= e.z { glam::Vec3::X * e.x } else { glam::Vec3::Z * e.z };
    let eye = c - axis * 0.45 - glam::Vec3::Y * (0.2 * e.y);
    let target = c + axis * 0.5 - glam::Vec3::Y * (0.1 * e.y);
    Camera::look_at(eye, target, glam::Vec3::Y, 70.0)
}

/// Renders `mesh` at `resolution x resolution` with `camera` (`None`: the automatic camera, [`Camera::frame`]) with
/// triangle `i` in the colour of class `classes[i]` (one class per triangle, each below `counts.len()`), and a
/// legend of `counts`. The rays are traced on the CPU (a BVH of `mesh`).
pub fn render_classes(
    mesh: &Mesh,
    classes: &[u32],
    counts: &[u64],
    resolution: u32,
    camera: Option<Camera>,
) -> Result<ClassImage, RenderError> {
    check_classes(mesh, classes, counts, resolution)?;
    let bvh = Bvh::build(mesh)?;
    let camera = camera.unwrap_or_else(|| Camera::frame(&mesh_bounds(mesh)));
    use rayon::prelude::*;
    let hits: Vec<Option<u32>> = (0..resolution * resolution)
        .into_par_iter()
        .map(|p| {
            let ray = camera.ray(p % resolution, p / resolution, resolution, resolution);
            bvh.intersect(&ray, &mut TraceCounters::default()).map(|h| h.triangle)
        })
        .collect();
    paint(mesh, classes, counts, resolution, &camera, &hits)
}

/// [`render_classes`] from hits traced elsewhere (a device, ray queries): `hits[p]` is the triangle of `mesh` that
/// the ray of pixel `p` (`camera.ray(p % resolution, p / resolution, resolution, resolution)`, row by row) hit
/// first, `None` for a miss.
pub fn render_classes_from_hits(
    mesh: &Mesh,
    classes: &[u32],
    counts: &[u64],
    resolution: u32,
    camera: &Camera,
    hits: &[Option<u32>],
) -> Result<ClassImage, RenderError> {
    check_classes(mesh, classes, counts, resolution)?;
    let pixels = u64::from(resolution) * u64::from(resolution);
    if hits.len() as u64 != pixels {
        return Err(RenderError::Invalid(format!("{} hits for {pixels} pixels", hits.len())));
    }
    if let Some(t) = hits.iter().flatten().find(|&&t| t as usize >= mesh.triangle_count()) {
        return Err(RenderError::Invalid(format!("hit triangle {t} of {} triangles", mesh.triangle_count())));
    }
    paint(mesh, classes, counts, resolution, camera, hits)
}

fn check_classes(mesh: &Mesh, classes: &[u32], counts: &[u64], resolution: u32) -> Result<(), RenderError> {
    if classes.len() != mesh.triangle_count() {
        return Err(RenderError::Invalid(format!(
            "{} classes for {} triangles (characterize every triangle: sample stride 1)",
            classes.len(),
            mesh.triangle_count()
        )));
    }
    let k = u32::try_from(counts.len()).map_err(|_| RenderError::Invalid("too many classes".into()))?;
    if k == 0 || classes.iter().any(|&c| c >= k) {
        return Err(RenderError::Invalid(format!("a triangle's class is not below k = {k}")));
    }
    if !(16..=4096).contains(&resolution) {
        return Err(RenderError::Invalid(format!("resolution {resolution} outside 16..=4096")));
    }
    Ok(())
}

/// The picture of per-pixel hits (checked by the callers): Lambert-shaded class colours, the share bar and the
/// legend.
fn paint(
    mesh: &Mesh,
    classes: &[u32],
    counts: &[u64],
    resolution: u32,
    camera: &Camera,
    hits: &[Option<u32>],
) -> Result<ClassImage, RenderError> {
    let k = counts.len() as u32;
    let (w, rh) = (resolution, resolution);
    let per_row = (w / ENTRY_W).max(1);
    let rows = k.div_ceil(per_row);
    let height = rh + 8 + BAR_H + 6 + rows * ROW_H + 4;
    let mut img = ClassImage {
        width: w,
        height,
        render_height: rh,
        pixels: vec![BACKGROUND; (w * height) as usize],
        triangle: vec![None; (w * rh) as usize],
        classes: k,
        counts: counts.to_vec(),
        bar: (rh + 8, BAR_H),
    };
    for (p, hit) in hits.iter().enumerate() {
        let Some(t) = *hit else { continue };
        let ray = camera.ray(p as u32 % w, p as u32 / w, w, rh);
        let [a, b, cc] = mesh.triangle(t as usize);
        let lambert = (b - a).cross(cc - a).try_normalize().map_or(0.0, |n| n.dot(ray.dir).abs());
        let level = (lambert * (SHADE_LEVELS - 1) as f32).round() as u32;
        img.triangle[p] = Some(t);
        img.pixels[p] = shaded(classes[t as usize], level);
    }
    // Share bar: segment widths proportional to the counts (cumulative rounding, so they add up to the width).
    let total: u64 = counts.iter().sum::<u64>().max(1);
    let mut acc = 0u64;
    for (c, &n) in counts.iter().enumerate() {
        let x0 = (u128::from(acc) * u128::from(w) / u128::from(total)) as u32;
        acc += n;
        let x1 = (u128::from(acc) * u128::from(w) / u128::from(total)) as u32;
        img.fill(x0, rh + 8, x1 - x0, BAR_H, class_colour(c as u32));
    }
    // Swatches and counts, class order, left to right then top to bottom.
    for (c, &n) in counts.iter().enumerate() {
        let c = c as u32;
        let x = (c % per_row) * ENTRY_W + 4;
        let y = rh + 8 + BAR_H + 6 + (c / per_row) * ROW_H;
        img.fill(x, y, SWATCH, SWATCH, class_colour(c));
        draw_number(&mut img, x + SWATCH + 4, y + 1, n);
    }
    Ok(img)
}

/// Decodes a digit drawn by the legend at `(x, y)` (for tests): the digit whose bitmap matches, if any.
pub fn read_digit(img: &ClassImage, x: u32, y: u32) -> Option<u32> {
    (0..10u32).find(|&d| {
        DIGITS[d as usize].iter().enumerate().all(|(row, bits)| {
            (0..3u32).all(|col| {
                let ink = img.pixel(x + col * FONT_SCALE, y + row as u32 * FONT_SCALE) == INK;
                ink == (bits & (4 >> col) != 0)
            })
        })
    })
}

/// Reads the count of legend entry `c` back from the image (for tests).
pub fn read_legend_count(img: &ClassImage, c: u32) -> Option<u64> {
    let per_row = (img.width / ENTRY_W).max(1);
    let x = (c % per_row) * ENTRY_W + 4 + SWATCH + 4;
    let y = img.render_height + 8 + BAR_H + 6 + (c / per_row) * ROW_H + 1;
    let mut n: Option<u64> = None;
    for i in 0.. {
        let xd = x + i * 4 * FONT_SCALE;
        if xd + 3 * FONT_SCALE > img.width {
            break;
        }
        match read_digit(img, xd, y) {
            Some(d) => n = Some(n.unwrap_or(0) * 10 + u64::from(d)),
            None => break,
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shaded_colours_decode_to_their_class() {
        for k in [1u32, 5, 20, 32] {
            for c in 0..k {
                for l in 0..SHADE_LEVELS {
                    assert_eq!(decode_class(shaded(c, l), k), Some(c), "k {k} class {c} level {l}");
                }
            }
        }
        assert_eq!(decode_class(BACKGROUND, 32), None);
        assert_eq!(decode_class(INK, 32), None);
    }
}

//! `render::render_classes`: the PNG decodes with the right size, every pixel of the render area shows the class of
//! the triangle it hit, the legend bar's segments are the class shares, and the legend's digits read back as the
//! class counts.

use meshchar::characterize::{cpu, Params};
use meshchar::eval::render::{decode_class, read_legend_count, render_classes, BACKGROUND};

#[test]
fn picture_decodes_and_its_colours_map_back_to_classes() {
    let mesh = meshchar::mesh::default_teapot();
    let c = cpu::fast(&mesh, &Params { keep_per_triangle: true, ..Params::default() }).expect("characterize");
    let classes = c.per_triangle.as_ref().expect("per triangle").classes.clone();
    let img = render_classes(&mesh, &classes, &c.histogram, 128, None).expect("render");
    let bytes = img.encode_png().expect("png");

    // The PNG: signature, IHDR size, and pixels equal to the image's.
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let decoder = png::Decoder::new(std::io::Cursor::new(&bytes));
    let mut reader = decoder.read_info().expect("header");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("frame");
    assert_eq!((info.width, info.height, info.color_type), (128, img.height, png::ColorType::Rgb));
    let pixel = |x: u32, y: u32| {
        let i = 3 * (y * info.width + x) as usize;
        [buf[i], buf[i + 1], buf[i + 2]]
    };

    // Every render pixel: background where nothing was hit, else a shade of the hit triangle's class.
    let mut hits = 0;
    for y in 0..img.render_height {
        for x in 0..img.width {
            match img.triangle[(y * img.width + x) as usize] {
                None => assert_eq!(pixel(x, y), BACKGROUND),
                Some(t) => {
                    hits += 1;
                    assert_eq!(decode_class(pixel(x, y), c.classes), Some(classes[t as usize]), "pixel {x},{y}");
                }
            }
        }
    }
    assert!(hits > 128 * 128 / 10, "the teapot fills part of the frame: {hits} hits");

    // The share bar: the run of each class colour along a row is its share of the width (within 1 pixel).
    let (bar_y, _) = img.bar;
    let n: u64 = c.histogram.iter().sum();
    for (k, &count) in c.histogram.iter().enumerate() {
        let colour = meshchar::eval::render::class_colour(k as u32);
        let width = (0..img.width).filter(|&x| pixel(x, bar_y + 2) == colour).count() as f64;
        let share = count as f64 / n as f64 * img.width as f64;
        // Colours of other classes never repeat this one, so a run is this class's segment.
        assert!((width - share).abs() <= 1.0 + 1e-9, "class {k}: {width} px for a share of {share:.2} px");
    }

    // The legend's digits read back as the histogram.
    for (k, &count) in c.histogram.iter().enumerate() {
        assert_eq!(read_legend_count(&img, k as u32), Some(count), "legend of class {k}");
    }
}

#[test]
fn bad_input_is_an_error() {
    let mesh = meshchar::mesh::default_teapot();
    let n = mesh.triangle_count();
    assert!(render_classes(&mesh, &vec![0; n - 1], &[n as u64], 64, None).is_err(), "one class short");
    assert!(render_classes(&mesh, &vec![1; n], &[n as u64], 64, None).is_err(), "class beyond k");
    assert!(render_classes(&mesh, &vec![0; n], &[n as u64], 8, None).is_err(), "resolution too small");
    assert!(render_classes(&mesh, &vec![0; n], &[], 64, None).is_err(), "no classes");
}

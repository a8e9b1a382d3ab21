//! The multi-channel noise nodes (noise2d, noise3d, fractal2d, fractal3d as color3/vector3 and
//! color4/vector4): no second Perlin implementation is at hand, so each is checked against
//! properties the specification and MaterialX's definitions fix. Every channel is the float
//! node's noise at its own point (the first at the point itself, the fourth at the offset
//! MaterialX's definitions give), the three colour channels are the color3 node's, values stay
//! in the noise's range, move continuously, and the channels are decorrelated.

use super::*;

/// A Material `/M` emitting, in red, channel `channel` of node `id`'s output (`None`: the
/// output is a float): the channel is extracted by a downstream node and combined with green
/// and blue 1, so a negative value still emits (an emission with no positive channel is none).
fn emitting_channel(id: &str, inputs: &[&str], channel: Option<(&str, usize)>) -> String {
    let inputs: String = inputs.iter().map(|line| format!("        {line}\n")).collect();
    let (extract, source) = match channel {
        None => (String::new(), "</M/N.outputs:out>"),
        Some((extract, index)) => (
            format!(
                "    def Shader \"X\" {{\n        uniform token info:id = \"{extract}\"\n        \
                 color3f inputs:in.connect = </M/N.outputs:out>\n        int inputs:index = {index}\n        \
                 float outputs:out\n    }}\n"
            ),
            "</M/X.outputs:out>",
        ),
    };
    format!(
        "def Material \"M\" {{\n    token outputs:mtlx:surface.connect = </M/S.outputs:surface>\n    \
         def Shader \"S\" {{\n        uniform token info:id = \"ND_surface_unlit\"\n        \
         color3f inputs:emission_color.connect = </M/Y.outputs:out>\n        token outputs:surface\n    }}\n    \
         def Shader \"N\" {{\n        uniform token info:id = \"{id}\"\n{inputs}        color3f outputs:out\n    }}\n\
         {extract}    def Shader \"Y\" {{\n        uniform token info:id = \"ND_combine3_color3\"\n        \
         float inputs:in1.connect = {source}\n        float inputs:in2 = 1\n        float inputs:in3 = 1\n        \
         color3f outputs:out\n    }}\n}}"
    )
}

/// The compiled channel, as a function of the shading point (texture coordinates (x, y),
/// position (x, y, z): the 2D nodes read the first, the 3D nodes the second).
fn channel(id: &str, inputs: &[&str], channel: Option<(&str, usize)>) -> Box<dyn Fn([f32; 3]) -> f32> {
    let (code, rendered) = compiled(&emitting_channel(id, inputs, channel));
    let code = code.unwrap_or_else(|| panic!("{id} {channel:?}: {rendered}"));
    assert!(rendered.is_empty(), "{id} {channel:?}: {rendered}");
    let name = format!("{id} {channel:?}");
    Box::new(move |[x, y, z]: [f32; 3]| {
        let mut emitted = [0.0f32; 3];
        let g = Globals { p: [x, y, z], n: [0.0, 0.0, 1.0], ng: [0.0, 0.0, 1.0], u: x, v: y, ..Globals::default() };
        code.emission(&g, 0, &mut emitted).expect("emits");
        assert_eq!(emitted[1], 1.0, "{name}: the probe's green");
        emitted[0]
    })
}

/// Pearson's correlation of two samples.
fn correlation(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len() as f32;
    let (ma, mb) = (a.iter().sum::<f32>() / n, b.iter().sum::<f32>() / n);
    let cov: f32 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f32 = a.iter().map(|x| (x - ma) * (x - ma)).sum();
    let vb: f32 = b.iter().map(|y| (y - mb) * (y - mb)).sum();
    cov / (va * vb).sqrt()
}

#[test]
fn multi_channel_noise_is_the_float_noise_at_the_offsets_materialx_defines() {
    // (node, offset of the fourth channel in MaterialX's definitions, bound on |value|:
    // Perlin noise stays within ±1, three octaves of diminish 0.5 within ±1.75).
    let nodes: [(&str, [f32; 3], f32); 4] = [
        ("noise2d", [19.0, 73.0, 0.0], 1.0),
        ("noise3d", [19.0, 73.0, 29.0], 1.0),
        ("fractal2d", [19.0, 193.0, 0.0], 1.75),
        ("fractal3d", [19.0, 193.0, 17.0], 1.75),
    ];
    // Sample points: a fixed pseudo-random scatter over 100 lattice cells per axis, so most
    // pairs lie cells apart and the samples are nearly independent (a correlation estimate
    // over 1000 of them has a spread of about 0.03).
    let mut rng = Rng::new(7, 22, 0);
    let mut coordinate = || rng.uniform() * 100.0 - 50.0;
    let points: Vec<[f32; 3]> = (0..1000).map(|_| [coordinate(), coordinate(), coordinate()]).collect();
    for (node, offset, bound) in nodes {
        let planar = node.ends_with("2d");
        let float = channel(&format!("ND_{node}_float"), &[], None);
        let colour: Vec<_> =
            (0..3).map(|k| channel(&format!("ND_{node}_vector3"), &[], Some(("ND_extract_vector3", k)))).collect();
        let four: Vec<_> =
            (0..4).map(|k| channel(&format!("ND_{node}_vector4"), &[], Some(("ND_extract_vector4", k)))).collect();
        let mut samples = vec![Vec::new(); 4];
        for &p in &points {
            let p = if planar { [p[0], p[1], 0.0] } else { p };
            let values: Vec<f32> = four.iter().map(|f| f(p)).collect();
            // The fourth channel is the float noise at the offset point; the first is the
            // float noise itself; the colour channels are the color3 node's.
            let shifted = [p[0] + offset[0], p[1] + offset[1], p[2] + offset[2]];
            assert!(
                (values[3] - float(shifted)).abs() <= 1e-6,
                "{node} at {p:?}: w {} vs {}",
                values[3],
                float(shifted)
            );
            assert_eq!(values[0], float(p), "{node} at {p:?}: x");
            for k in 0..3 {
                assert_eq!(values[k], colour[k](p), "{node} at {p:?}: channel {k} of the colour node");
            }
            for (k, v) in values.iter().enumerate() {
                assert!(v.abs() <= bound, "{node} at {p:?}: channel {k} = {v}");
                samples[k].push(*v);
            }
            // Continuous: a step of 10⁻³ moves each channel by at most a bounded slope.
            let step = [p[0] + 1e-3, p[1] + 1e-3, if planar { 0.0 } else { p[2] + 1e-3 }];
            for (k, f) in four.iter().enumerate() {
                let moved = (f(step) - values[k]).abs();
                assert!(moved <= 0.03, "{node} at {p:?}: channel {k} jumps by {moved}");
            }
        }
        // Noise, not a constant, and four decorrelated channels.
        for (k, s) in samples.iter().enumerate() {
            let mean = s.iter().sum::<f32>() / s.len() as f32;
            let spread = (s.iter().map(|x| (x - mean) * (x - mean)).sum::<f32>() / s.len() as f32).sqrt();
            assert!(spread > 0.1 && mean.abs() < 0.1, "{node}: channel {k} mean {mean}, spread {spread}");
        }
        let mut largest = 0.0f32;
        for a in 0..4 {
            for b in a + 1..4 {
                let r = correlation(&samples[a], &samples[b]);
                assert!(r.abs() < 0.15, "{node}: channels {a} and {b} correlate ({r})");
                largest = largest.max(r.abs());
            }
        }
        eprintln!("{node}: largest correlation between channels {largest:.3}");
    }
}

#[test]
fn multi_channel_noise_scales_each_channel_by_its_amplitude_and_adds_the_pivot() {
    // out = noise · amplitude + pivot per channel (fractals have no pivot); a float amplitude
    // (the `FA` variants) scales all four channels.
    let p = [0.37, -1.21, 0.83];
    for (node, pivot) in [("noise2d", Some(0.5)), ("noise3d", Some(-0.25)), ("fractal2d", None), ("fractal3d", None)] {
        let pivot_line = pivot.map(|x| format!("float inputs:pivot = {x}")).unwrap_or_default();
        for k in 0..4 {
            let unit = channel(&format!("ND_{node}_vector4"), &[], Some(("ND_extract_vector4", k)))(p);
            let amplitude = [0.5, 2.0, 1.5, 3.0];
            let scaled = channel(
                &format!("ND_{node}_color4"),
                &["color4f inputs:amplitude = (0.5, 2, 1.5, 3)", &pivot_line],
                Some(("ND_extract_color4", k)),
            )(p);
            let want = unit * amplitude[k] + pivot.unwrap_or(0.0);
            assert!((scaled - want).abs() < 1e-5, "{node} channel {k}: {scaled} vs {want}");
            let by_float = channel(
                &format!("ND_{node}_vector4FA"),
                &["float inputs:amplitude = 2", &pivot_line],
                Some(("ND_extract_vector4", k)),
            )(p);
            let want = unit * 2.0 + pivot.unwrap_or(0.0);
            assert!((by_float - want).abs() < 1e-5, "{node}FA channel {k}: {by_float} vs {want}");
        }
    }
}

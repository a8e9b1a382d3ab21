//! Scenes and substance files generated as text: layer stacks of any depth over a sphere, the
//! inputs `strata bench` measures and the tests that check its claims share (the layered
//! transport, the per-material layer-mode choice, allocation-free sampling).

use std::fmt::Write;

/// The shader that thresholds noise into a soft-edged mask, shared by every generated stack.
const THRESHOLD_SHADER: &str = "shader threshold(float value = 0.0, float edge = 0.5, float softness = 0.1, output float out) {\n    \
     out = smoothstep(edge, edge + max(softness, 1e-4), value);\n}\n\n";

/// A `.ash` file with `n` substances `layer_0` … : each a noise-thresholded mask (none on the
/// bottom layer, which is opaque) over a diffuse or glossy surface of its own colour.
pub fn layered_source(n: usize) -> String {
    stack_source(n, MaskKind::Noise, THRESHOLD_SHADER.to_string())
}

/// A scene: a camera, a dome and a distant light, and a unit sphere with `n` slots bound to
/// the substances of [`layered_source`] in `file`.
pub fn layered_scene(n: usize, file: &str) -> String {
    let mut s = String::from(
        r#"#usda 1.0
def Xform "World"
{
    def Camera "Camera"
    {
        float focalLength = 50
        float horizontalAperture = 36
        float verticalAperture = 36
        float3 xformOp:translate = (0, 0, 4)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def DomeLight "Sky"
    {
        float inputs:intensity = 0.8
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 2
        float inputs:angle = 3
        float3 xformOp:rotateXYZ = (-40, 30, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }
    def Sphere "Ball"
    {
        double radius = 1
"#,
    );
    for k in 0..n {
        writeln!(s, "        rel material:slotBinding:_{:03} = </Looks/L{k}>", k * 10).unwrap();
    }
    s += "    }\n}\n\ndef Scope \"Looks\"\n{\n";
    for k in 0..n {
        writeln!(
            s,
            "    def Material \"L{k}\"\n    {{\n        def Shader \"Surface\"\n        {{\n            \
             uniform token info:implementationSource = \"sourceAsset\"\n            \
             uniform asset info:strata:sourceAsset = @{file}@\n            \
             uniform token info:strata:sourceAsset:subIdentifier = \"layer_{k}\"\n        }}\n    }}"
        )
        .unwrap();
    }
    s += "}\n";
    s
}

/// How the layers of a [`mask_stack_source`] are masked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaskKind {
    /// Constant masks chosen so that every layer has the same weight `1/n` (layer `k` from the
    /// bottom has mask `1/(k+1)`): all the noise of stochastic picking comes from the pick.
    Constant,
    /// Noise thresholded at 0.5 (about half coverage each), as in `bench render`.
    Noise,
    /// Thin high-contrast stripes: mask 1 on 3 % of the surface, 0 elsewhere, a different
    /// direction and phase per layer.
    Thin,
}

impl MaskKind {
    /// All kinds, in chart order.
    pub const ALL: [MaskKind; 3] = [MaskKind::Constant, MaskKind::Noise, MaskKind::Thin];

    /// Short name for file names and labels.
    pub fn name(self) -> &'static str {
        match self {
            MaskKind::Constant => "constant",
            MaskKind::Noise => "noise",
            MaskKind::Thin => "thin",
        }
    }
}

/// Coverage of one [`MaskKind::Thin`] stripe layer.
pub const THIN_COVERAGE: f64 = 0.03;

/// A `.ash` file with `n` substances `layer_0` … over a sphere (see [`layered_scene`]), masked
/// as `kind` says; the bottom layer is opaque.
pub fn mask_stack_source(n: usize, kind: MaskKind) -> String {
    let header = format!(
        "{THRESHOLD_SHADER}shader stripes(float dx = 1.0, float dy = 0.0, float freq = 8.0, float phase = 0.0, float width = 0.03, output float out) {{\n    \
         float f = (P[0] * dx + P[1] * dy + P[2] * 0.3) * freq + phase;\n    \
         out = f - floor(f) < width ? 1.0 : 0.0;\n}}\n\n"
    );
    stack_source(n, kind, header)
}

/// `header` then `n` substances `layer_0` …, alternately diffuse and glossy in colours around
/// the hue circle, each above the bottom one masked as `kind` says.
fn stack_source(n: usize, kind: MaskKind, mut s: String) -> String {
    for k in 0..n {
        let h = k as f32 / n.max(1) as f32 * 6.0;
        let c = |o: f32| 0.15 + 0.7 * (((h + o) % 6.0 - 3.0).abs() - 1.0).clamp(0.0, 1.0);
        let (r, g, b) = (c(0.0), c(4.0), c(2.0));
        writeln!(s, "substance layer_{k} {{").unwrap();
        if k % 2 == 0 {
            writeln!(s, "    node s = diffuse(albedo: color({r:.3}, {g:.3}, {b:.3}));").unwrap();
        } else {
            writeln!(s, "    node s = glossy(albedo: color({r:.3}, {g:.3}, {b:.3}), roughness: 0.3);").unwrap();
        }
        s += "    surface = s.bsdf;\n";
        if k > 0 {
            match kind {
                MaskKind::Constant => writeln!(s, "    node m = mask(opacity: {:.9});", 1.0 / (k + 1) as f64).unwrap(),
                MaskKind::Noise => {
                    writeln!(s, "    node n = noise(scale: {:.3});", 2.0 + 1.37 * k as f32).unwrap();
                    s += "    node t = threshold(value: n.out, edge: 0.5, softness: 0.1);\n";
                    s += "    node m = mask(opacity: t.out);\n";
                }
                MaskKind::Thin => {
                    let a = k as f64 * 2.399_963;
                    writeln!(
                        s,
                        "    node t = stripes(dx: {:.4}, dy: {:.4}, phase: {:.4}, width: {THIN_COVERAGE});",
                        a.cos(),
                        a.sin(),
                        (k as f64 * 0.618_034).fract()
                    )
                    .unwrap();
                    s += "    node m = mask(opacity: t.out);\n";
                }
            }
            s += "    mask = m.out;\n";
        }
        s += "}\n\n";
    }
    s
}

//! A plane wave meeting the flat top of a glass slab, and what Fresnel's
//! and Snell's laws say the light volume reads on either side: written
//! out here and in the independent photon tracer's Fresnel
//! (`eikon_testkit::photon_ref::fresnel`), not the engine's.

use eikon_testkit::photon_ref::fresnel;
use eikon_wavefront::LightVolume;

/// The slab's index (the ambient's is 1).
const N_SLAB: f64 = 1.5;
/// The grid: `RES`^3 cells over [-1, 1]^3.
const RES: usize = 32;
/// The slab's top surface, `y = Y_SURFACE`; the slab fills what is below.
const Y_SURFACE: f64 = -0.2;

/// A plane wave of unit irradiance at incidence `deg` (in the x-y plane)
/// on the slab's top: from the air above it (`from_air`), or from within
/// the glass, travelling up.
#[derive(Clone, Copy, Debug)]
pub struct Slab {
    /// Angle of incidence, degrees.
    pub deg: f64,
    /// The light comes from the air (else from within the glass).
    pub from_air: bool,
}

impl Slab {
    /// The scene file.
    pub fn scene(&self) -> String {
        let (s, c) = self.deg.to_radians().sin_cos();
        let dir_y = if self.from_air { -c } else { c };
        format!(
            "[grid]\nresolution = {RES}\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
             [ambient]\nindex = 1.0\n\
             [[object]]\nname = \"slab\"\n\
             shape = {{ type = \"box\", center = [0.0, {}, 0.0], size = [40.0, 2.8, 40.0] }}\n\
             index = {N_SLAB}\nextinction = [0, 0, 0]\n\
             [[light]]\ntype = \"directional\"\ndirection = [{s}, {dir_y}, 0]\npower = [1, 1, 1]\n",
            Y_SURFACE - 1.4
        )
    }

    /// The mean fluence expected and read (channel 0) on the incident side
    /// (incident plus reflected wave: `1 + R`, or 1 when the reflection is
    /// not traced) and on the far side (the transmitted wave: `1 - R`,
    /// narrowed or widened by `cos_i / cos_t`), over the cells that the
    /// part of the surface within the grid lights, two cells clear of it
    /// and of the grid's faces, and clear of the light that enters the
    /// grid's side within the slab without crossing its top.
    pub fn measure(&self, v: &LightVolume, reflections: bool) -> ([f64; 2], [f64; 2]) {
        let ((s, c), (st, ct)) = self.angles();
        let h = 2.0 / RES as f64;
        let ys = Y_SURFACE;
        let at = |i: usize, j: usize| (-1.0 + (i as f64 + 0.5) * h, -1.0 + (j as f64 + 0.5) * h);
        // Height above the surface on the incident side, and the room
        // there and on the far side.
        let up = |y: f64| if self.from_air { y - ys } else { ys - y };
        let (room_near, room_far) = if self.from_air {
            (1.0 - ys, 1.0 + ys)
        } else {
            (1.0 + ys, 1.0 - ys)
        };
        let inner = |k: usize, x: f64| (3..RES - 3).contains(&k) && x.abs() < 0.9;
        let near = |i, j, k| {
            let (x, y) = at(i, j);
            // Where the reflected ray through the cell left the surface.
            let xh = x - up(y) * s / c;
            inner(k, x) && up(y) > 2.0 * h && up(y) < room_near - 3.0 * h && xh.abs() < 0.85
        };
        let far = |i, j, k| {
            let (x, y) = at(i, j);
            let depth = -up(y);
            // Where the transmitted ray through the cell crossed the
            // surface.
            let xh = x - depth * st / ct;
            inner(k, x)
                && depth > 2.0 * h
                && depth < room_far - 3.0 * h
                && xh.abs() < 0.85
                && x > -1.0 + depth * s / c + 2.0 * h
        };
        let mean = |keep: &dyn Fn(usize, usize, usize) -> bool| {
            let (mut sum, mut count) = (0.0, 0);
            for i in 0..RES {
                for j in 0..RES {
                    for k in 0..RES {
                        if keep(i, j, k) {
                            sum += f64::from(v.fluence[[i, j, k, 0]]);
                            count += 1;
                        }
                    }
                }
            }
            assert!(count > 100, "{self:?}: {count} cells");
            sum / count as f64
        };
        let (want_near, want_far) = self.expected(reflections);
        ([want_near, mean(&near)], [want_far, mean(&far)])
    }

    /// The sines and cosines of the angles of incidence and refraction.
    fn angles(&self) -> ((f64, f64), (f64, f64)) {
        let (s, c) = self.deg.to_radians().sin_cos();
        let st = s * self.indices().0 / self.indices().1;
        ((s, c), (st, (1.0 - st * st).sqrt()))
    }

    /// The indices on the incident side and on the far side.
    fn indices(&self) -> (f64, f64) {
        if self.from_air {
            (1.0, N_SLAB)
        } else {
            (N_SLAB, 1.0)
        }
    }

    /// The fluence on the incident side and on the far side.
    fn expected(&self, reflections: bool) -> (f64, f64) {
        let ((_, c), (_, ct)) = self.angles();
        let (n1, n2) = self.indices();
        let r = fresnel(c, n1, n2).0;
        (if reflections { 1.0 + r } else { 1.0 }, (1.0 - r) * c / ct)
    }

    /// The mean fluence expected and read (channel 0) in the layer of cells
    /// the surface cuts and in the next layer on the incident side, wholly
    /// there: each cell holds the incident side's fluence over its part on
    /// that side and the far side's over the rest ([`Self::measure`]'s two
    /// values, its exact cell average). Away from the grid's sides: at
    /// normal incidence (either way), or from the air up to 45 degrees,
    /// over the cells the light reaches through the grid's top.
    pub fn cut_layers(&self, v: &LightVolume, reflections: bool) -> [[f64; 2]; 2] {
        let oblique = self.deg != 0.0;
        assert!(
            !oblique || (self.from_air && self.deg <= 45.0),
            "{self:?}: the cut layers are measured at normal incidence, or from the air up to 45 degrees"
        );
        let (near, far) = self.expected(reflections);
        let h = 2.0 / RES as f64;
        let j = ((Y_SURFACE + 1.0) / h).floor() as usize;
        let below = (Y_SURFACE - (-1.0 + j as f64 * h)) / h;
        assert!(below > 0.1 && below < 0.9, "the surface cuts layer {j}");
        let (incident, next) = if self.from_air {
            (1.0 - below, j + 1)
        } else {
            (below, j - 1)
        };
        let is = if oblique {
            RES / 2..RES / 2 + 10
        } else {
            3..RES - 3
        };
        let layer = |j: usize| {
            let (mut sum, mut count) = (0.0, 0);
            for i in is.clone() {
                for k in 3..RES - 3 {
                    sum += f64::from(v.fluence[[i, j, k, 0]]);
                    count += 1;
                }
            }
            sum / count as f64
        };
        [
            [incident * near + (1.0 - incident) * far, layer(j)],
            [near, layer(next)],
        ]
    }
}

//! The image of the network: the particles' radiance toward the camera gathered and splatted
//! front to back with the medium's transmittance (illumination networks 3.3, its last paragraph).

use super::*;

/// The image of the splats: pixels, and how many splats were left out where more than a
/// pixel holds overlapped it (the farthest go).
pub struct Splatted {
    pub image: crate::output::Image,
    pub dropped: u64,
    /// Pixels that came out non-finite and were set to 0.
    pub nonfinite: u32,
}

impl Illumination {
    /// The image (paper 3.3's last paragraph) with the scene's camera: each particle's
    /// radiance toward the camera (glsl/networks/gather.comp), then the particles splatted
    /// front to back with alpha blending (glsl/networks/splat.comp), Gaussian footprints of the
    /// particle's radius b carrying its extinction cross-section sigma_t m.
    /// `width`: the footprint's width in particle radii. `medium_step`: > 0 scales each
    /// camera ray's splats so that their optical depths sum to the medium's along the ray
    /// (marched in steps of it, scene units; `networks.transmittance = medium`), 0 keeps the
    /// splats' own (the paper's).
    pub fn image(&self, gpu: &Gpu, net: &Network, width: f32, medium_step: f32) -> Result<Splatted, SolverError> {
        let gs = &self.gs;
        let n = self.push.particles;
        let colour = gpu.buffer("networks colours", 16 * n as u64)?;
        let [w, h] = self.size;
        let pixels = gpu.buffer("networks image", 16 * w as u64 * h as u64)?;
        // The particles nearest the camera first (distance from a perspective camera, depth
        // along an orthographic one's axis; ties by index): splat.comp appends in this order.
        let (origin, axis) = self.camera;
        let key = |x: &Vec3| match axis {
            Some(a) => (*x - origin).dot(a),
            None => (*x - origin).length(),
        };
        let keys: Vec<f32> = net.particles.positions.iter().map(key).collect();
        let mut order: Vec<u32> = (0..n).collect();
        order.sort_by(|a, b| keys[*a as usize].total_cmp(&keys[*b as usize]).then(a.cmp(b)));
        let order = gpu.buffer_with("networks splat order", &order)?;
        let gather = gpu.pipeline(&GATHER, &gs.modelled.spec())?;
        let splat = gpu.pipeline(&SPLAT, &gs.modelled.view_spec())?;
        let (sigma_m, sky) = (self.sigma_m, self.push.sky);
        let passes = [
            gs.bind(Pass::new("networks.gather", QueueRole::Trace, &gather))
                .read(3, &self.positions)
                .read(4, &self.dirs)
                .read(5, &self.direct)
                .read(6, &self.field[self.current])
                .write(7, &colour)
                .read(8, self.emitted())
                .read(9, self.arriving())
                .push(&GatherPush {
                    particles: n,
                    directions: self.push.directions,
                    units: self.push.units,
                    direct: (self.env_dirs == 0) as u32,
                    emission: self.emission.code(),
                })
                .cover([n, 1, 1]),
            gs.bind(Pass::new("networks.splat", QueueRole::Trace, &splat))
                .read(3, &self.positions)
                .read(4, &colour)
                .write(5, &pixels)
                .read(6, &order)
                .push(&SplatPush {
                    sigma_m: [sigma_m.x, sigma_m.y, sigma_m.z, 0.0],
                    sky,
                    width: net.particle_radius() as f32 * width,
                    particles: n,
                    step: medium_step,
                    pad: 0,
                })
                .cover([w, h, 1]),
        ];
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
        let px: Vec<[f32; 4]> = gpu.read_buffer_as(&pixels)?;
        if px.iter().any(|p| p[3] < 0.0) {
            return Err(SolverError::Unsupported(
                "networks: a pixel's splats ran past the per-invocation loop guard; use fewer networks.particles"
                    .to_string(),
            ));
        }
        let mut nonfinite = 0u32;
        let data = px
            .iter()
            .flat_map(|p| {
                let ok = p[..3].iter().all(|c| c.is_finite());
                nonfinite += (!ok) as u32;
                if ok {
                    [p[0], p[1], p[2]]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        Ok(Splatted {
            image: crate::output::Image { width: w, height: h, data },
            dropped: px.iter().map(|p| p[3] as u64).sum(),
            nonfinite,
        })
    }
}

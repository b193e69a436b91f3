//! `eikon trace`: one ray through a scene, with its whole path.

use crate::output::{fmt_vec, parse_vec3};
use anyhow::{bail, Result};
use clap::ValueEnum;
use eikon_grid::{ray, trace, AnalyticField, Form, IndexField, Scene, TraceOptions};
use glam::DVec3;
use serde_json::json;
use std::path::PathBuf;

#[derive(Clone, Copy, PartialEq, Eq, Debug, ValueEnum)]
enum Integrator {
    /// Forward Euler [Ihrke07 eqs 11-12], first order.
    Euler,
    /// Classical fourth-order Runge-Kutta.
    Rk4,
    /// Adaptive Dormand-Prince 5(4); --step is the largest step.
    Dopri5,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug, ValueEnum)]
enum FormArg {
    /// Equal distance per step [Ihrke07 eqs 9-10], as for eye rays.
    Distance,
    /// Equal optical path per step [Ihrke07 eqs 14-15], as for light.
    Time,
}

/// The flag value that selects `v` (`rk4`, `dopri5`, `time`...): what the
/// user typed, for the output, rather than an internal type name.
fn flag_name<T: ValueEnum>(v: &T) -> String {
    v.to_possible_value()
        .map(|p| p.get_name().to_string())
        .unwrap_or_default()
}

/// A path longer than this many diagonals of the bounds has circled inside
/// for a long time; its exit deserves a word of caution.
const LONG_PATH_DIAGONALS: f64 = 10.0;

/// Arguments of `eikon trace`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Ray origin x,y,z in world units (outside the bounds is fine).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    origin: DVec3,
    /// Initial direction x,y,z (normalized for you).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    dir: DVec3,
    /// Integration scheme.
    #[arg(long, value_enum, default_value = "rk4")]
    integrator: Integrator,
    /// Parameterization of the ray equation.
    #[arg(long, value_enum, default_value = "distance")]
    form: FormArg,
    /// Step size in voxels (the smallest voxel edge).
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true)]
    step: f64,
    /// Local error target for dopri5, in voxels.
    #[arg(long, default_value_t = 1e-4, allow_hyphen_values = true)]
    tolerance: f64,
    /// Give up after this many steps (reported as status max-steps).
    #[arg(long, default_value_t = 1_000_000)]
    max_steps: usize,
    /// Sample the scene's analytic index exactly instead of the voxel grid.
    #[arg(long)]
    analytic: bool,
    /// `sharp` (exact surfaces, each region's own index) or `smoothed`
    /// (the voxel grid's smoothed index), instead of the scene's
    /// `[grid] interfaces`.
    #[arg(long, value_parser = crate::grid::parse_interfaces)]
    interfaces: Option<eikon_grid::Interfaces>,
    /// Colour channel 0, 1 or 2 (R, G, B) of a dispersive scene.
    #[arg(long, default_value_t = 0)]
    channel: usize,
    /// Print every k-th path point (0: none; the exit is always printed).
    #[arg(long, default_value_t = 1)]
    every: usize,
    /// Print the result as JSON.
    #[arg(long)]
    json: bool,
}

/// Run `eikon trace`.
pub fn run(args: Args) -> Result<()> {
    if !(args.step.is_finite() && args.step > 0.0) {
        bail!(
            "--step: must be a positive number of voxels, got {}",
            args.step
        );
    }
    if !(args.tolerance.is_finite() && args.tolerance > 0.0) {
        bail!("--tolerance: must be positive, got {}", args.tolerance);
    }
    if args.dir.length() == 0.0 {
        bail!("--dir: must be a non-zero vector");
    }
    if args.channel > 2 {
        bail!("--channel: must be 0, 1 or 2, got {}", args.channel);
    }
    let scene = Scene::load_with(
        &args.scene,
        &eikon_grid::GridOverride {
            interfaces: args.interfaces,
            ..Default::default()
        },
    )?;
    let sharp = scene.grid.interfaces == eikon_grid::Interfaces::Sharp;
    if sharp && args.analytic {
        bail!("--analytic: samples the smoothed-interface scene's profiles; with sharp interfaces every region's profile is already exact (leave --analytic out)");
    }
    let geom = scene.grid.geometry.clone();
    let form = match args.form {
        FormArg::Distance => Form::EqualDistance,
        FormArg::Time => Form::EqualTime,
    };
    let method = match args.integrator {
        Integrator::Euler => ray::Integrator::Euler,
        Integrator::Rk4 => ray::Integrator::Rk4,
        Integrator::Dopri5 => ray::Integrator::DormandPrince,
    };
    let opts = TraceOptions {
        tolerance: args.tolerance * geom.voxel_size(),
        max_steps: args.max_steps,
        record_path: true,
        ..TraceOptions::in_voxels(&geom, form, method, args.step)
    };
    let medium;
    if args.analytic {
        let sharp: Vec<&str> = scene
            .objects
            .iter()
            .filter(|o| matches!(o.material.index, eikon_grid::IndexProfile::Constant(_)))
            .map(|o| o.name.as_str())
            .collect();
        if !sharp.is_empty() {
            eprintln!(
                "warning: --analytic samples index profiles exactly; the surfaces of constant-index objects ({}) are discontinuities without a gradient there, so rays pass them unbent",
                sharp.join(", ")
            );
        }
    }
    let (field, source): (Box<dyn IndexField>, String) = if sharp {
        (
            Box::new(AnalyticField::new(&scene, args.channel)),
            format!(
                "sharp interfaces, each region's own index, channel {}",
                args.channel.min(scene.channels() - 1)
            ),
        )
    } else if args.analytic {
        (
            Box::new(AnalyticField::new(&scene, args.channel)),
            "analytic index".into(),
        )
    } else {
        medium = crate::output::build_medium(&scene)?;
        let ch = args.channel.min(medium.channels() - 1);
        (
            Box::new(medium.field(ch)),
            format!("voxel field, channel {ch}"),
        )
    };
    let end = if sharp {
        let regions = eikon_grid::Regions::new(&scene);
        eikon_grid::region::trace(
            &regions,
            args.origin,
            args.dir,
            &opts,
            args.channel.min(scene.channels() - 1),
        )
    } else {
        trace(field.as_ref(), &geom, args.origin, args.dir, &opts)
    };
    let integrator = flag_name(&args.integrator);
    let form_name = flag_name(&args.form);
    let exited = end.status == eikon_grid::Status::Exited;
    let length: f64 = end.path.windows(2).map(|w| w[0].distance(w[1])).sum();
    let diagonal = (geom.max - geom.min).length();
    let every = args.every;
    let shown: Vec<DVec3> = if every == 0 {
        Vec::new()
    } else {
        end.path.iter().copied().step_by(every).collect()
    };
    if args.json {
        let v = json!({
            "scene": args.scene.display().to_string(),
            "field": source,
            "integrator": integrator,
            "form": form_name,
            "step_voxels": args.step,
            "status": end.status.name(),
            "entry": end.entry.to_array(),
            // Only an exited ray has an exit; "position" is where it ended.
            "exit": exited.then(|| end.position.to_array()),
            "position": end.position.to_array(),
            "path_length": length,
            "direction": end.direction.to_array(),
            "optical_path": end.optical_path,
            "steps": end.steps,
            "rejected_steps": end.rejected,
            "path": shown.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("scene         {} ({source})", args.scene.display());
        println!(
            "integrator    {integrator}, {form_name} form, step {} voxel = {:.6} world units",
            args.step, opts.step
        );
        if every > 0 {
            println!("path          {} points (every {every}):", end.path.len());
            for p in &shown {
                println!("  {:>12.6} {:>12.6} {:>12.6}", p.x, p.y, p.z);
            }
        }
        println!("status        {}", end.status.name());
        println!("entry         {}", fmt_vec(end.entry));
        let label = if exited { "exit" } else { "last position" };
        println!("{label:<13} {}", fmt_vec(end.position));
        println!("direction     {}", fmt_vec(end.direction));
        println!("optical path  {:.9}", end.optical_path);
        println!("steps         {} ({} rejected)", end.steps, end.rejected);
        println!("path length   {length:.6} world units");
    }
    if exited && length > LONG_PATH_DIAGONALS * diagonal {
        // A ray trapped by total internal reflection can only leave the
        // integrated path through step and voxel error: say so rather
        // than let "exited" read as the physics.
        eprintln!(
            "note: the ray exited after a path {:.0} times the bounds' diagonal; a trapped ray (total internal reflection) can leak out through step or voxel error: check with a smaller --step",
            length / diagonal
        );
    }
    match end.status {
        eikon_grid::Status::Exited | eikon_grid::Status::Missed => Ok(()),
        eikon_grid::Status::MaxSteps => {
            bail!(
                "the ray did not leave the volume within --max-steps {} steps",
                args.max_steps
            )
        }
        eikon_grid::Status::Diverged => bail!("the ray diverged (non-finite state)"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_names_are_the_flag_values() {
        assert_eq!(flag_name(&Integrator::Euler), "euler");
        assert_eq!(flag_name(&Integrator::Rk4), "rk4");
        assert_eq!(flag_name(&Integrator::Dopri5), "dopri5");
        assert_eq!(flag_name(&FormArg::Distance), "distance");
        assert_eq!(flag_name(&FormArg::Time), "time");
        // And each name parses back to its value.
        for i in Integrator::value_variants() {
            assert_eq!(Integrator::from_str(&flag_name(i), false), Ok(*i));
        }
        for f in FormArg::value_variants() {
            assert_eq!(FormArg::from_str(&flag_name(f), false), Ok(*f));
        }
    }
}

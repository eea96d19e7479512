//! Material spec strings, as given on the command line:
//!
//! * `lambert:albedo=R/G/B` (or one value for grey)
//! * `ward:rho_d=D,alpha=A[,rho_s=S]` (D and S grey or R/G/B; rho_s defaults to 1 - rho_d)
//! * `ggx:alpha=A[,diffuse=R/G/B][,specular=R/G/B]` (diffuse defaults to 0, specular to 1)
//! * `nbrdf:NAME` (bundled) or `nbrdf:PATH.json`
//! * `merl:PATH[,lookup=nearest|trilinear]`
//! * `rgl:PATH.bsdf`

use super::analytic::{Ggx, Lambert, Ward};
use super::merl::{Lookup, MerlTable};
use super::nbrdf::NeuralBrdf;
use super::rgl::RglBsdf;
use super::{BrdfError, Material};
use glam::DVec3;
use std::collections::BTreeMap;
use std::path::Path;

/// Parse a spec string and load whatever it names.
pub fn parse_material(spec: &str) -> Result<Box<dyn Material>, BrdfError> {
    let (kind, rest) = spec
        .split_once(':')
        .ok_or_else(|| BrdfError::spec(spec, "expected KIND:PARAMS, e.g. lambert:albedo=0.5"))?;
    match kind {
        "lambert" | "ward" | "ggx" => Ok(parse_analytic(spec)?.into_material()),
        "nbrdf" => {
            let looks_like_path =
                rest.ends_with(".json") || rest.contains('/') || rest.contains(std::path::MAIN_SEPARATOR);
            if rest.is_empty() {
                Err(BrdfError::spec(spec, "expected nbrdf:NAME or nbrdf:PATH.json"))
            } else if looks_like_path {
                Ok(Box::new(NeuralBrdf::read(Path::new(rest))?))
            } else {
                Ok(Box::new(NeuralBrdf::bundled(rest)?))
            }
        }
        "merl" => {
            let (path, lookup) = match rest.rsplit_once(",lookup=") {
                Some((p, "nearest")) => (p, Lookup::Nearest),
                Some((p, "trilinear")) => (p, Lookup::Trilinear),
                Some((_, other)) => {
                    return Err(BrdfError::spec(
                        spec,
                        format!("lookup '{other}' is not nearest or trilinear"),
                    ))
                }
                None => (rest, Lookup::Nearest),
            };
            if path.is_empty() {
                return Err(BrdfError::spec(spec, "expected merl:PATH"));
            }
            let mut table = MerlTable::read(Path::new(path))?;
            table.lookup = lookup;
            Ok(Box::new(table))
        }
        "rgl" => {
            if rest.is_empty() {
                return Err(BrdfError::spec(spec, "expected rgl:PATH.bsdf"));
            }
            Ok(Box::new(RglBsdf::read(Path::new(rest))?))
        }
        other => Err(BrdfError::spec(
            spec,
            format!("unknown material kind '{other}' (lambert, ward, ggx, nbrdf, merl, rgl)"),
        )),
    }
}

/// An analytic material with its parameters: what `fit` produces and what a plan is built from.
#[derive(Clone, Debug, PartialEq)]
pub enum Analytic {
    Lambert(Lambert),
    Ward(Ward),
    Ggx(Ggx),
}

/// An analytic model evaluates without boxing (a reconstruction's fitted prior, per query).
impl Material for Analytic {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        match self {
            Analytic::Lambert(m) => m.eval(wi, wo),
            Analytic::Ward(m) => m.eval(wi, wo),
            Analytic::Ggx(m) => m.eval(wi, wo),
        }
    }
}

impl Analytic {
    pub fn into_material(self) -> Box<dyn Material> {
        match self {
            Analytic::Lambert(m) => Box::new(m),
            Analytic::Ward(m) => Box::new(m),
            Analytic::Ggx(m) => Box::new(m),
        }
    }

    /// The spec string that parses back to this material.
    pub fn to_spec(&self) -> String {
        let rgb = |c: DVec3| {
            if c.x == c.y && c.y == c.z {
                format!("{}", c.x)
            } else {
                format!("{}/{}/{}", c.x, c.y, c.z)
            }
        };
        match self {
            Analytic::Lambert(m) => format!("lambert:albedo={}", rgb(m.albedo)),
            Analytic::Ward(m) => format!("ward:rho_d={},alpha={},rho_s={}", rgb(m.rho_d), m.alpha, rgb(m.rho_s)),
            Analytic::Ggx(m) => format!(
                "ggx:alpha={},diffuse={},specular={}",
                m.alpha,
                rgb(m.diffuse),
                rgb(m.specular)
            ),
        }
    }
}

/// Parse `lambert:...`, `ward:...` or `ggx:...` (see the module doc).
pub fn parse_analytic(spec: &str) -> Result<Analytic, BrdfError> {
    let (kind, rest) = spec
        .split_once(':')
        .ok_or_else(|| BrdfError::spec(spec, "expected KIND:PARAMS"))?;
    let mut params = BTreeMap::new();
    for item in rest.split(',').filter(|s| !s.trim().is_empty()) {
        let (k, v) = item
            .split_once('=')
            .ok_or_else(|| BrdfError::spec(spec, format!("'{item}' is not KEY=VALUE")))?;
        if params.insert(k.trim(), v.trim()).is_some() {
            return Err(BrdfError::spec(spec, format!("'{}' given twice", k.trim())));
        }
    }
    let allowed: &[&str] = match kind {
        "lambert" => &["albedo"],
        "ward" => &["rho_d", "alpha", "rho_s"],
        "ggx" => &["alpha", "diffuse", "specular"],
        other => {
            return Err(BrdfError::spec(
                spec,
                format!("'{other}' is not an analytic model (lambert, ward, ggx)"),
            ))
        }
    };
    if let Some(k) = params.keys().find(|k| !allowed.contains(k)) {
        return Err(BrdfError::spec(
            spec,
            format!("unknown parameter '{k}' for {kind} (allowed: {})", allowed.join(", ")),
        ));
    }
    let number = |key: &str, text: &str| -> Result<f64, BrdfError> {
        let v: f64 = text
            .parse()
            .map_err(|_| BrdfError::spec(spec, format!("{key}: '{text}' is not a number")))?;
        if !(v.is_finite() && v >= 0.0) {
            return Err(BrdfError::spec(
                spec,
                format!("{key} must be finite and >= 0, got {text}"),
            ));
        }
        Ok(v)
    };
    let colour = |key: &str| -> Result<Option<DVec3>, BrdfError> {
        let Some(text) = params.get(key) else { return Ok(None) };
        let parts: Vec<&str> = text.split('/').collect();
        match parts.as_slice() {
            [g] => Ok(Some(DVec3::splat(number(key, g)?))),
            [r, g, b] => Ok(Some(DVec3::new(number(key, r)?, number(key, g)?, number(key, b)?))),
            _ => Err(BrdfError::spec(
                spec,
                format!("{key}: expected one value or R/G/B, got '{text}'"),
            )),
        }
    };
    let required = |key: &str| BrdfError::spec(spec, format!("{kind} needs {key}="));
    let alpha = || -> Result<f64, BrdfError> { number("alpha", params.get("alpha").ok_or_else(|| required("alpha"))?) };
    Ok(match kind {
        "lambert" => Analytic::Lambert(Lambert {
            albedo: colour("albedo")?.ok_or_else(|| required("albedo"))?,
        }),
        "ward" => {
            let rho_d = colour("rho_d")?.ok_or_else(|| required("rho_d"))?;
            let rho_s = match colour("rho_s")? {
                Some(s) => s,
                None if rho_d.max_element() <= 1.0 => DVec3::ONE - rho_d,
                None => {
                    return Err(BrdfError::spec(
                        spec,
                        "rho_d > 1 leaves no default rho_s = 1 - rho_d; give rho_s",
                    ))
                }
            };
            Analytic::Ward(Ward {
                rho_d,
                rho_s,
                alpha: alpha()?,
            })
        }
        _ => Analytic::Ggx(Ggx {
            alpha: alpha()?,
            diffuse: colour("diffuse")?.unwrap_or(DVec3::ZERO),
            specular: colour("specular")?.unwrap_or(DVec3::ONE),
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::frame::from_spherical;

    #[test]
    fn parses_the_analytic_specs() {
        let w = parse_analytic("ward:rho_d=0.25,alpha=0.1").expect("ward");
        assert_eq!(
            w,
            Analytic::Ward(Ward {
                rho_d: DVec3::splat(0.25),
                rho_s: DVec3::splat(0.75),
                alpha: 0.1
            })
        );
        let g = parse_analytic("ggx:alpha=0.2,diffuse=0.1/0.2/0.3").expect("ggx");
        assert_eq!(
            g,
            Analytic::Ggx(Ggx {
                alpha: 0.2,
                diffuse: DVec3::new(0.1, 0.2, 0.3),
                specular: DVec3::ONE
            })
        );
        assert_eq!(parse_analytic(&g.to_spec()).ok(), Some(g));
        let l = parse_material("lambert:albedo=0.5/0.5/0.5").expect("lambert");
        let f = l.eval(from_spherical(0.1, 0.0), from_spherical(0.2, 1.0));
        assert!((f.x - 0.5 / std::f64::consts::PI).abs() < 1e-15);
        assert!(parse_material("nbrdf:alum-bronze").is_ok());
    }

    #[test]
    fn refuses_bad_specs_with_one_clear_line() {
        let msg = |s: &str| parse_material(s).err().map(|e| e.to_string()).unwrap_or_default();
        assert_eq!(
            msg("ward:rho_d=0.2"),
            "bad material spec 'ward:rho_d=0.2': ward needs alpha="
        );
        assert_eq!(
            msg("ggx:alpha=-1"),
            "bad material spec 'ggx:alpha=-1': alpha must be finite and >= 0, got -1"
        );
        assert_eq!(
            msg("ggx:alpha=nan"),
            "bad material spec 'ggx:alpha=nan': alpha must be finite and >= 0, got nan"
        );
        assert_eq!(msg("ggx:alpha=0.1,beta=2"), "bad material spec 'ggx:alpha=0.1,beta=2': unknown parameter 'beta' for ggx (allowed: alpha, diffuse, specular)");
        assert_eq!(
            msg("lambert:albedo=1/2"),
            "bad material spec 'lambert:albedo=1/2': albedo: expected one value or R/G/B, got '1/2'"
        );
        assert_eq!(
            msg("ward:alpha=1,alpha=2,rho_d=0"),
            "bad material spec 'ward:alpha=1,alpha=2,rho_d=0': 'alpha' given twice"
        );
        assert_eq!(
            msg("phong:n=3"),
            "bad material spec 'phong:n=3': unknown material kind 'phong' (lambert, ward, ggx, nbrdf, merl, rgl)"
        );
        assert_eq!(
            msg("lambert"),
            "bad material spec 'lambert': expected KIND:PARAMS, e.g. lambert:albedo=0.5"
        );
        assert!(msg("nbrdf:no-such-material").starts_with("no bundled nbrdf material 'no-such-material'"));
        assert!(msg("merl:/nonexistent.binary").starts_with("/nonexistent.binary: "));
        assert_eq!(
            msg("merl:x.binary,lookup=cubic"),
            "bad material spec 'merl:x.binary,lookup=cubic': lookup 'cubic' is not nearest or trilinear"
        );
    }
}

#[cfg(test)]
mod extremes {
    use super::*;
    use crate::brdf::analytic::Ggx;
    use crate::brdf::frame::from_spherical;

    /// Every material kind, loaded through its spec string (files written to a temp dir), is finite
    /// and non-negative at theta in {0, 89.9, 90} deg for both directions, and 0 below the horizon.
    #[test]
    fn every_kind_is_finite_at_the_extremes() {
        let dir = tempfile::tempdir().expect("temp dir");
        let ggx = Ggx {
            alpha: 0.2,
            diffuse: DVec3::splat(0.1),
            specular: DVec3::ONE,
        };
        let merl = dir.path().join("m.binary");
        MerlTable::tabulate(&ggx).write(&merl).expect("merl");
        let rgl = dir.path().join("r.bsdf");
        std::fs::write(&rgl, crate::brdf::rgl::tabulate_ggx(&ggx, 0.2, 4, 32, 16)).expect("rgl");
        let nb = dir.path().join("n.json");
        std::fs::write(&nb, crate::brdf::nbrdf_bundled::BUNDLED[0].1).expect("json");
        let specs = [
            "lambert:albedo=0.5".to_string(),
            "ward:rho_d=0.2,alpha=0".to_string(),
            "ward:rho_d=0.2,alpha=0.05".to_string(),
            "ggx:alpha=1e-6,diffuse=0.2".to_string(),
            "ggx:alpha=1".to_string(),
            "nbrdf:chrome".to_string(),
            format!("nbrdf:{}", nb.display()),
            format!("merl:{}", merl.display()),
            format!("merl:{},lookup=trilinear", merl.display()),
            format!("rgl:{}", rgl.display()),
        ];
        let angles = [0.0_f64, 89.9, 90.0].map(f64::to_radians);
        for spec in &specs {
            let m = parse_material(spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
            for &ti in &angles {
                for &to in &angles {
                    for phi in [0.0, 1.0, std::f64::consts::PI] {
                        let (wi, wo) = (from_spherical(ti, 0.0), from_spherical(to, phi));
                        let f = m.eval(wi, wo);
                        assert!(f.is_finite() && f.min_element() >= 0.0, "{spec} ti {ti} to {to}: {f}");
                        assert_eq!(m.eval(wi, -wo), DVec3::ZERO, "{spec}");
                        assert_eq!(m.eval(-wi, wo), DVec3::ZERO, "{spec}");
                    }
                }
            }
        }
    }
}

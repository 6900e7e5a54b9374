//! Degenerate scenes by name, for the "no catastrophe" checks of the selection: `degenerate:NAME:TRIANGLES[:SEED]`
//! is a scene wherever the tools take a path (like `family:` specs, see [`super::families`]; the evaluation layer's
//! `eval::scene` reads them, the file loaders do not), built by the seeded
//! generators of [`super::generate`] that the failure study uses (`docs/failure-study.md`).
//!
//! | name | [`Degenerate`] | the scene (`n` = TRIANGLES) |
//! |---|---|---|
//! | `flat` | [`Degenerate::Flat`] | `n` small triangles in the plane `z = 0` ([`generate::flat`]) |
//! | `collinear` | [`Degenerate::Collinear`] | `n` triangles whose centroids lie on the x axis ([`generate::collinear_centroids`]; no seed) |
//! | `all-equal` | [`Degenerate::AllEqual`] | `n` copies of one triangle ([`generate::all_equal`]; no seed) |
//! | `zero-area` | [`Degenerate::ZeroArea`] | `n` triangles of zero area ([`generate::zero_area`]) |
//! | `overlapping` | [`Degenerate::Overlapping`] | `n` large triangles with vertices uniform in the unit cube ([`generate::overlapping_large`]) |
//! | `fan` | [`Degenerate::Fan`] | a polygon of `n` triangles over three points: coincident copies and zero-area legs ([`generate::fan_polygon`]; no seed) |
//! | `lattice` | [`Degenerate::Lattice`] | a flat `k x k` lattice of squares plus `m` collinear zero-area triangles along its diagonal, `m = n / 451`, `k = floor(sqrt((n - m) / 2))`: `2 k^2 + m <= n` triangles (exactly `n` for `n = 180_400`: `k = 300`, `m = 400`) ([`generate::lattice_with_diagonal`]; no seed) |
//! | `duplicated` | [`Degenerate::Duplicated`] | a random soup of `n / 4` triangles, each 4 times ([`generate::duplicated`]; `4 floor(n / 4)` triangles) |
//! | `huge` | [`Degenerate::Huge`] | a random soup of `n` triangles scaled by `1e30` |
//! | `tiny` | [`Degenerate::Tiny`] | the same scaled by `1e-30` |
//! | `long-thin` | [`Degenerate::LongThin`] | one sliver along the scene's diagonal and `n - 1` small triangles ([`generate::long_thin`]) |
//!
//! The same name, count and seed give the same mesh bit for bit. Counts above [`MAX_DEGENERATE_TRIANGLES`] are
//! refused with an error.

use super::{generate, Mesh, MeshError};

/// Largest triangle count of a degenerate scene: `2^26`, as for the families.
pub const MAX_DEGENERATE_TRIANGLES: usize = super::families::MAX_FAMILY_TRIANGLES;

/// The prefix of a degenerate scene's name: `degenerate:NAME:TRIANGLES[:SEED]` ([`parse_spec`]).
pub const SPEC_PREFIX: &str = "degenerate:";

/// A degenerate scene kind (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Degenerate {
    /// Small triangles in one plane.
    Flat,
    /// Centroids on a line.
    Collinear,
    /// Copies of one triangle.
    AllEqual,
    /// Zero-area triangles only.
    ZeroArea,
    /// Large overlapping triangles.
    Overlapping,
    /// A fan polygon over three points.
    Fan,
    /// A flat lattice with collinear zero-area triangles along its diagonal.
    Lattice,
    /// A soup with every triangle four times.
    Duplicated,
    /// A soup at coordinates near `1e30`.
    Huge,
    /// A soup at coordinates near `1e-30`.
    Tiny,
    /// One sliver across the scene plus small triangles.
    LongThin,
}

impl Degenerate {
    /// Every kind, in the order of the module docs.
    pub const ALL: [Degenerate; 11] = [
        Degenerate::Flat,
        Degenerate::Collinear,
        Degenerate::AllEqual,
        Degenerate::ZeroArea,
        Degenerate::Overlapping,
        Degenerate::Fan,
        Degenerate::Lattice,
        Degenerate::Duplicated,
        Degenerate::Huge,
        Degenerate::Tiny,
        Degenerate::LongThin,
    ];

    /// The name in specs (`flat`, `collinear`, `all-equal`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Degenerate::Flat => "flat",
            Degenerate::Collinear => "collinear",
            Degenerate::AllEqual => "all-equal",
            Degenerate::ZeroArea => "zero-area",
            Degenerate::Overlapping => "overlapping",
            Degenerate::Fan => "fan",
            Degenerate::Lattice => "lattice",
            Degenerate::Duplicated => "duplicated",
            Degenerate::Huge => "huge",
            Degenerate::Tiny => "tiny",
            Degenerate::LongThin => "long-thin",
        }
    }
}

impl std::str::FromStr for Degenerate {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Degenerate::ALL.into_iter().find(|d| d.name().eq_ignore_ascii_case(s.trim())).ok_or_else(|| {
            let names: Vec<&str> = Degenerate::ALL.iter().map(|d| d.name()).collect();
            format!("unknown degenerate scene {s:?} ({})", names.join(", "))
        })
    }
}

/// A degenerate scene named on a command line or in a record: `degenerate:NAME:TRIANGLES[:SEED]` (seed 0 when left
/// out; `TRIANGLES` as in [`super::families::parse_spec`]). `None` when `s` does not start with [`SPEC_PREFIX`];
/// otherwise the kind, the count and the seed, or why the spec is wrong.
pub fn parse_spec(s: &str) -> Option<Result<(Degenerate, usize, u64), String>> {
    let rest = s.strip_prefix(SPEC_PREFIX)?;
    let parts: Vec<&str> = rest.split(':').collect();
    let usage = format!("{s:?}: a degenerate scene is degenerate:NAME:TRIANGLES[:SEED]");
    Some((|| {
        if !(2..=3).contains(&parts.len()) {
            return Err(usage.clone());
        }
        let kind: Degenerate = parts[0].parse()?;
        let (n, seed) = super::families::count_and_seed(&parts[1..], &usage)?;
        Ok((kind, n, seed))
    })())
}

/// The scene of `kind` for `triangles` and `seed` (see the module docs for what the count means per kind).
///
/// Fails with [`MeshError::Invalid`] above [`MAX_DEGENERATE_TRIANGLES`].
pub fn generate(kind: Degenerate, triangles: usize, seed: u64) -> Result<Mesh, MeshError> {
    let n = triangles;
    if n > MAX_DEGENERATE_TRIANGLES {
        return Err(MeshError::Invalid {
            file: format!("{SPEC_PREFIX}{}:{n}:{seed}", kind.name()),
            reason: format!("{n} triangles: more than the {MAX_DEGENERATE_TRIANGLES} a degenerate scene may have"),
        });
    }
    let mut mesh = match kind {
        Degenerate::Flat => generate::flat(n, seed),
        Degenerate::Collinear => generate::collinear_centroids(n),
        Degenerate::AllEqual => generate::all_equal(n),
        Degenerate::ZeroArea => generate::zero_area(n, seed),
        Degenerate::Overlapping => generate::overlapping_large(n, seed),
        Degenerate::Fan => generate::fan_polygon(n),
        Degenerate::Lattice => {
            let m = n / 451;
            let k = (((n - m) / 2) as f64).sqrt().floor() as usize;
            // The square root of an exact square may round below it: step k to the largest with 2 k^2 <= n - m.
            let k = (k.saturating_sub(1)..=k + 1).rev().find(|k| 2 * k * k <= n - m).unwrap_or(0);
            generate::lattice_with_diagonal(k, m)
        }
        Degenerate::Duplicated => generate::duplicated(&generate::random_soup(n / 4, seed), 4)?,
        Degenerate::Huge => generate::scaled(&generate::random_soup(n, seed), 1e30)?,
        Degenerate::Tiny => generate::scaled(&generate::random_soup(n, seed), 1e-30)?,
        Degenerate::LongThin => generate::long_thin(n, seed),
    };
    mesh.name = format!("{SPEC_PREFIX}{}:{n}:{seed}", kind.name());
    Ok(mesh)
}

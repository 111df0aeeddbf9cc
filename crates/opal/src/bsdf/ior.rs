//! Indices of refraction by name, as Mitsuba 3's scene format accepts them.
//!
//! * [`dielectric_ior`]: Mitsuba's named dielectric indices (`int_ior="bk7"`, `ext_ior="air"`,
//!   ...); the values are the standard refractive indices Mitsuba documents for its
//!   `dielectric`, `plastic`, ... plugins (at ≈ 589 nm, 20 °C).
//! * [`conductor_ior`]: the RGB complex index `(η, κ)` of a conductor by Mitsuba material name
//!   (`material="Au"`). Derived by `bench/scripts/conductor_ior_rgb.py` from the spectral data
//!   Mitsuba ships (`data/ior/*.spd`: "data from www.luxpop.com database", compiled from
//!   E. D. Palik (ed.), *Handbook of Optical Constants of Solids* I (1985) and II (1991),
//!   Academic Press, plus LLNL/CXRO tables): n(λ), κ(λ) integrated against the CIE 1931 2°
//!   colour-matching functions over 360–830 nm, Y-normalised, XYZ → linear sRGB. These agree
//!   with the values Mitsuba 3.9.1 uses in its RGB variants to ≤ 4·10⁻⁴ (printed by the
//!   script). `"none"` is not in the table: it means a perfect mirror, `F = 1`.
//!
//! Tests (below): lookups, case of unknown names.

/// Mitsuba's named dielectric indices of refraction.
const DIELECTRICS: &[(&str, f32)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.333),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.470),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.575),
    ("diamond", 2.419),
];

/// `(name, η (r, g, b), κ (r, g, b))`, see the module documentation for the derivation.
const CONDUCTORS: &[(&str, [f32; 3], [f32; 3])] = &[
    ("Ag", [0.15527, 0.11673, 0.13838], [4.8283, 3.1223, 2.1467]),
    ("Al", [1.6575, 0.88041, 0.5212], [9.2238, 6.2696, 4.8366]),
    ("Au", [0.14304, 0.37529, 1.442], [3.983, 2.3856, 1.6032]),
    ("Be", [4.185, 3.1851, 2.7838], [3.8354, 3.0102, 2.8688]),
    ("Cr", [4.3696, 2.9165, 1.6548], [5.2065, 4.2314, 3.7544]),
    ("Cu", [0.20098, 0.92377, 1.1021], [3.9132, 2.4531, 2.1419]),
    ("Cu2O", [3.5517, 2.9499, 2.7517], [0.11421, 0.19389, 0.60608]),
    ("CuO", [3.2475, 2.4478, 2.21], [0.52109, 0.57004, 0.72212]),
    ("Hg", [2.3989, 1.44, 0.9095], [6.3275, 4.372, 3.4215]),
    ("Ir", [3.0863, 2.0822, 1.6178], [5.5921, 4.0671, 3.267]),
    ("K", [0.064043, 0.04641, 0.038182], [2.1042, 1.349, 0.91305]),
    ("Li", [0.26579, 0.19562, 0.22093], [3.5401, 2.3111, 1.6685]),
    ("Mo", [4.4839, 3.5252, 2.7761], [4.1114, 3.4209, 3.1504]),
    ("Na_palik", [0.060269, 0.056142, 0.061984], [3.1793, 2.1125, 1.5789]),
    ("Nb", [3.4201, 2.7901, 2.3954], [3.4414, 2.7377, 2.5795]),
    ("Ni_palik", [2.3673, 1.6634, 1.467], [4.4988, 3.0502, 2.3453]),
    ("Rh", [2.5858, 1.8602, 1.5541], [6.7822, 4.703, 3.9758]),
    ("Ta", [2.0627, 2.393, 2.6277], [2.4083, 1.7415, 1.9469]),
    ("TiN", [1.6484, 1.1505, 1.3797], [3.3683, 1.9435, 1.102]),
    ("V_palik", [4.2775, 3.513, 2.7609], [3.4913, 2.8895, 3.1113]),
    ("W", [4.3708, 3.3003, 2.9982], [3.5006, 2.6049, 2.2731]),
    ("a-C", [2.944, 2.2272, 1.968], [0.88746, 0.79931, 0.81522]),
];

/// The index of refraction Mitsuba calls `name` (case-insensitive), if known.
pub fn dielectric_ior(name: &str) -> Option<f32> {
    let n = name.to_ascii_lowercase();
    DIELECTRICS.iter().find(|(k, _)| *k == n).map(|(_, v)| *v)
}

/// Names [`dielectric_ior`] knows.
pub fn dielectric_names() -> Vec<&'static str> {
    DIELECTRICS.iter().map(|(k, _)| *k).collect()
}

/// RGB `(η, κ)` of the conductor Mitsuba calls `name` (case-sensitive, as Mitsuba's file names).
pub fn conductor_ior(name: &str) -> Option<([f32; 3], [f32; 3])> {
    CONDUCTORS.iter().find(|(k, _, _)| *k == name).map(|(_, e, k)| (*e, *k))
}

/// Names [`conductor_ior`] knows (plus `none`, the perfect mirror).
pub fn conductor_names() -> Vec<&'static str> {
    CONDUCTORS.iter().map(|(k, _, _)| *k).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookups() {
        assert_eq!(dielectric_ior("BK7"), Some(1.5046));
        assert_eq!(dielectric_ior("polypropylene"), Some(1.49));
        assert_eq!(dielectric_ior("unobtainium"), None);
        let (eta, k) = conductor_ior("Au").unwrap();
        // gold: low η in red, high in blue; strong absorption
        assert!(eta[0] < 0.2 && eta[2] > 1.4 && k[0] > 3.9);
        assert!(conductor_ior("au").is_none() && conductor_ior("none").is_none());
        assert!(conductor_names().len() >= 20);
    }
}

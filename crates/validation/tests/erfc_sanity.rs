mod common;

/// The reference erfc the closed-form truth relies on, against tabulated values.
#[test]
fn erfc_matches_tabulated_values_to_1e12_relative() {
    let table = [
        (0.0, 1.0),
        (0.5, 0.479_500_122_186_953_5),
        (1.0, 0.157_299_207_050_285_13),
        (2.0, 0.004_677_734_981_047_266),
        (3.0, 2.209_049_699_858_544e-5),
        (4.0, 1.541_725_790_028_002e-8),
    ];
    for (x, want) in table {
        let got = common::erfc(x);
        assert!(((got - want) / want).abs() < 1e-12, "erfc({x}) = {got}, expected {want}");
    }
    // Φ⁻¹(1 − 1e-3) really gives 1e-3.
    let p = 0.5 * common::erfc(common::Z_1E3 / std::f64::consts::SQRT_2);
    assert!((p - 1e-3).abs() < 1e-12, "Q(3.0902…) = {p}");
}

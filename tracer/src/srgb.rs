//! Linear light to 8-bit sRGB and back.
//!
//! Encoding is the step where a last-bit difference between machines would change a byte of
//! the PNG, so it uses no transcendental function at run time: an 8-bit value `k` is chosen by
//! comparing the linear value with the 255 fixed thresholds `decode((k + ½) / 255)` (the
//! linear values where rounding `255 · encode(x)` moves from `k` to `k + 1`). The table is
//! computed in 50-digit decimal arithmetic and rounded once to `f64`; a test checks it against
//! the formula. Encoding is then exact round-to-nearest of the sRGB curve, identical on every
//! machine. To find `k` without a binary search over the 255 thresholds (eight dependent
//! comparisons per channel, a large share of a one-ray-per-pixel render), `[0, 1)` is cut into `BUCKETS` equal buckets; `FIRST` holds the code at each
//! bucket's lower end, and since no bucket holds more than one threshold (the thresholds are
//! at least 3.0e-4 apart, a bucket 2.4e-4 wide; a test checks it), one comparison finishes
//! the job. The answer is the same count of thresholds at or below `x`, exactly.

use crate::math::Color;

/// `THRESHOLDS[k]` is the linear value at which the 8-bit code moves from `k` to `k + 1`.
#[rustfmt::skip]
#[allow(clippy::excessive_precision, clippy::unreadable_literal)]
const THRESHOLDS: [f64; 255] = [
    0.00015176349177441876, 0.00045529047532325625, 0.0007588174588720937, 0.0010623444424209313,
    0.0013658714259697686, 0.0016693984095186062, 0.0019729253930674436, 0.002276452376616281,
    0.0025799793601651187, 0.0028835063437139563, 0.0031883009044305307, 0.003509259349581229,
    0.0038483149330964255, 0.004205748030104946, 0.004581832740528378, 0.004976837250274022,
    0.005391024159806378, 0.005824650784040896, 0.006277969426914104, 0.006751227633498622,
    0.007244668422128917, 0.007758530498667859, 0.008293048454762324, 0.008848452951698497,
    0.009424970891266087, 0.010022825574869033, 0.010642236851973573, 0.011283421258858294,
    0.011946592148522126, 0.01263195981251186, 0.013339731595349031, 0.014070112002164466,
    0.014823302800086412, 0.015599503113873269, 0.016398909516233674, 0.0172217161132341,
    0.018068114625156378, 0.018938294463134067, 0.019832442801866853, 0.020750744648685503,
    0.021693382909216234, 0.022660538449872057, 0.023652390157379497, 0.024669114995532,
    0.02571088805934576, 0.02677788262677978, 0.027870270208169255, 0.02898822059350997,
    0.030131901897720904, 0.03130148060400286, 0.03249712160540221, 0.03371898824468107,
    0.03496724235258794, 0.03624204428461637, 0.0375435529563331, 0.03887192587735157,
    0.04022731918402183, 0.04160988767090287, 0.0430197848210794, 0.04445716283538091,
    0.045922172660557446, 0.04741496401646279, 0.04893568542229297, 0.05048448422192487,
    0.052061506608397194, 0.05366689764757337, 0.055300801301023834, 0.05696336044816294,
    0.05865471690767354, 0.06037501145825081, 0.06212438385869472, 0.06390297286737921,
    0.0657109162611246, 0.06754835085349804, 0.06941541251256608, 0.07131223617812141,
    0.07323895587840543, 0.07519570474634667, 0.07718261503533431, 0.079199818134545,
    0.08124744458384038, 0.08332562408825164, 0.085434485532067, 0.0875741569925368,
    0.08974476575321061, 0.09194643831691976, 0.09417930041841838, 0.09644347703669502,
    0.09873909240696692, 0.10106627003236779, 0.10342513269534022, 0.10581580246874268,
    0.10823840072668098, 0.11069304815507362, 0.11317986476196004, 0.1156989698875601,
    0.11825048221409341, 0.12083451977536606, 0.12345119996613242, 0.12610063955123932,
    0.1287829546745594, 0.13149826086772048, 0.13424667305863716, 0.13702830557985105,
    0.1398432721766851, 0.14269168601521828, 0.14557365969008557, 0.14848930523210868,
    0.1514387341157627, 0.15442205726648323, 0.15743938506781888, 0.16049082736843368,
    0.1635764934889634, 0.16669649222873034, 0.1698509318723205, 0.17303992019602685,
    0.1762635644741625, 0.1795219714852476, 0.18281524751807324, 0.18614349837764557,
    0.18950682939101374, 0.19290534541298454, 0.19633915083172687, 0.19980834957426888,
    0.2033130451118906, 0.206853340465415, 0.21042933821039972, 0.21404114048223244,
    0.21768884898113217, 0.22137256497705868, 0.22509238931453274, 0.22884842241736905,
    0.23264076429332445, 0.2364695145386629, 0.24033477234264, 0.24423663649190822,
    0.24817520537484553, 0.25215057698580884, 0.25616284892931374, 0.2602121184241433,
    0.26429848230738645, 0.26842203703840817, 0.2725828787027534, 0.27678110301598513,
    0.28101680532745965, 0.2852900806240388, 0.28960102353374223, 0.29394972832933935,
    0.29833628893188435, 0.3027607989141932, 0.3072233515042661, 0.311724039588655,
    0.31626295571577834, 0.3208401920991836, 0.32545584062075916, 0.3301099928338964,
    0.33480273996660287, 0.3395341729245681, 0.34430438229418253, 0.34911345834551083,
    0.3539614910352206, 0.358848570009467, 0.3637747846067348, 0.368740223860638,
    0.3737449765026788, 0.3787891309649657, 0.3838727753828925, 0.38899599759777825,
    0.39415888515946956, 0.39936152532890534, 0.4046040050806453, 0.40988641110536267,
    0.41520882981230184, 0.4205713473317014, 0.4259740495171839, 0.43141702194811204,
    0.43690034993191285, 0.44242411850636965, 0.44798841244188314, 0.4535933162437015,
    0.45923891415412066, 0.464925290154655, 0.4706525279681791, 0.4764207110610407,
    0.4822299226451467, 0.48808024568002034, 0.4939717628748329, 0.4999045566904078,
    0.5058787093411996, 0.511894302797247, 0.5179514187861012, 0.5240501387947287,
    0.5301905440713919, 0.5363727156275035, 0.5425967342394596, 0.548862680450449,
    0.5551706345722391, 0.5615206766869422, 0.5679128866487572, 0.5743473440856915,
    0.5808241284012619, 0.5873433187761735, 0.5939049941699805, 0.6005092333227248,
    0.6071561147565556, 0.613845716777331, 0.6205781174761987, 0.6273533947311589,
    0.6341716262086089, 0.6410328893648691, 0.647937261447692, 0.6548848194977526,
    0.6618756403501223, 0.6689098006357256, 0.6759873767827806, 0.6831084450182221,
    0.690273081369109, 0.6974813616640163, 0.7047333615344105, 0.7120291564160101,
    0.719368821550131, 0.7267524319850168, 0.734180062577154, 0.7416517879925731,
    0.7491676827081358, 0.7567278210128071, 0.7643322770089145, 0.7719811246133927,
    0.7796744375590163, 0.787412289395617, 0.7951947534912902, 0.8030219030335867,
    0.8108938110306931, 0.8188105503125995, 0.826772193532254, 0.8347788131667057,
    0.8428304815182367, 0.8509272707154805, 0.85906925271453, 0.867256499300034,
    0.8754890820862817, 0.8837670725182769, 0.8920905418728011, 0.9004595612594652,
    0.9088742016217514, 0.9173345337380436, 0.9258406282226487, 0.9343925555268064,
    0.9429903859396901, 0.9516341895893966, 0.9603240364439273, 0.9690599963121588,
    0.9778421388448043, 0.9866705335353662, 0.9955452497210775,];

/// How many equal buckets [`encode_u8`] cuts `[0, 1)` into. A power of two, so that `x ·
/// BUCKETS` and `i / BUCKETS` are exact and the bucket of `x` is found without rounding.
const BUCKETS: usize = 4096;

/// `FIRST[i]`: the number of thresholds at or below `i / BUCKETS`, the code of the bucket's
/// lower end (computed at compile time from [`THRESHOLDS`]).
static FIRST: [u8; BUCKETS] = first_codes();

const fn first_codes() -> [u8; BUCKETS] {
    let mut out = [0u8; BUCKETS];
    let (mut i, mut k) = (0, 0);
    while i < BUCKETS {
        let lower = i as f64 / BUCKETS as f64;
        while k < THRESHOLDS.len() && THRESHOLDS[k] <= lower {
            k += 1;
        }
        out[i] = k as u8;
        i += 1;
    }
    out
}

/// The sRGB transfer function, encoded value in `[0, 1]` to linear.
pub fn decode(v: f64) -> f64 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The inverse sRGB transfer function, linear to encoded, both in `[0, 1]`.
#[cfg(test)]
pub fn encode(x: f64) -> f64 {
    if x <= 0.0031308 {
        x * 12.92
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Linear value (clamped to `[0, 1]`; NaN counts as 0) to its nearest 8-bit sRGB code.
#[inline]
pub fn encode_u8(x: f64) -> u8 {
    // The code is the number of thresholds ≤ x. None is ≤ 0 (the first is 1.5e-4), nor ≤
    // NaN, which fails `x > 0`; all are ≤ 1.
    if !(x > 0.0) {
        return 0;
    }
    if x >= 1.0 {
        return 255;
    }
    // 0 < x < 1, so `x · BUCKETS` is in (0, BUCKETS), exactly, and truncating it is the
    // floor: `i / BUCKETS ≤ x < (i + 1) / BUCKETS`. (Through `i32`: a float-to-`usize` cast
    // is a long instruction sequence on x86-64, to `i32` one instruction and two clamps.)
    let i = (x * BUCKETS as f64) as i32 as usize;
    let k = FIRST[i.min(BUCKETS - 1)];
    // The bucket holds at most one threshold above its lower end: the one at index `k`.
    let step = THRESHOLDS.get(usize::from(k)).is_some_and(|&t| t <= x);
    k + u8::from(step)
}

/// A linear colour as three 8-bit sRGB codes.
#[inline]
pub fn encode_rgb8(c: Color) -> [u8; 3] {
    [encode_u8(c.x), encode_u8(c.y), encode_u8(c.z)]
}

/// Decoding table for 8-bit sRGB textures: `LUT[k] = decode(k / 255)`.
pub fn decode_table() -> [f32; 256] {
    let mut t = [0.0f32; 256];
    for (k, v) in t.iter_mut().enumerate() {
        *v = decode(k as f64 / 255.0) as f32;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds_match_the_transfer_function() {
        for (k, &t) in THRESHOLDS.iter().enumerate() {
            let expected = decode((k as f64 + 0.5) / 255.0);
            assert!(
                (t - expected).abs() <= 4.0 * f64::EPSILON * expected,
                "threshold {k}: {t} vs {expected}"
            );
        }
        assert!(THRESHOLDS.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn encoding_rounds_the_curve_to_nearest() {
        for i in 0..=10_000 {
            let x = f64::from(i) / 10_000.0;
            let reference = (encode(x) * 255.0).round();
            let got = f64::from(encode_u8(x));
            // Ties can go either way only within a few ulps of a threshold.
            let near_tie = THRESHOLDS.iter().any(|t| (t - x).abs() < 1e-12);
            assert!(
                got == reference || near_tie,
                "x = {x}: {got} vs {reference}"
            );
        }
    }

    /// The count of thresholds ≤ x by binary search: what `encode_u8` must equal.
    fn by_search(x: f64) -> u8 {
        THRESHOLDS.partition_point(|&t| t <= x) as u8
    }

    #[test]
    fn no_bucket_holds_two_thresholds() {
        // One comparison after the table lookup is enough only if this holds.
        for (i, &first) in FIRST.iter().enumerate() {
            let lower = i as f64 / BUCKETS as f64;
            let upper = (i + 1) as f64 / BUCKETS as f64;
            let inside = THRESHOLDS
                .iter()
                .filter(|&&t| t > lower && t < upper)
                .count();
            assert!(inside <= 1, "bucket {i} holds {inside} thresholds");
            assert_eq!(first, by_search(lower));
        }
    }

    #[test]
    fn the_bucketed_lookup_equals_the_binary_search() {
        // Every threshold and its neighbouring doubles (where a wrong step would show),
        // every bucket edge and its neighbours, and a dense sweep.
        let mut xs: Vec<f64> = Vec::new();
        for &t in &THRESHOLDS {
            xs.extend([t, t.next_up(), t.next_down()]);
        }
        for i in 0..=BUCKETS {
            let e = i as f64 / BUCKETS as f64;
            xs.extend([e, e.next_up(), e.next_down()]);
        }
        xs.extend((0..=200_000).map(|i| f64::from(i) / 200_000.0));
        xs.extend([f64::MIN_POSITIVE, 5e-324, -0.0, 1.0 - f64::EPSILON / 2.0]);
        for x in xs {
            assert_eq!(encode_u8(x), by_search(x), "x = {x:e}");
        }
    }

    #[test]
    fn out_of_range_and_nan_clamp() {
        assert_eq!(encode_u8(-1.0), 0);
        assert_eq!(encode_u8(f64::NAN), 0);
        assert_eq!(encode_u8(0.0), 0);
        assert_eq!(encode_u8(1.0), 255);
        assert_eq!(encode_u8(7.5), 255);
        assert_eq!(encode_u8(f64::INFINITY), 255);
    }

    #[test]
    fn decode_then_encode_is_the_identity_on_codes() {
        let lut = decode_table();
        for k in 0..=255u8 {
            assert_eq!(encode_u8(f64::from(lut[k as usize])), k);
        }
    }
}

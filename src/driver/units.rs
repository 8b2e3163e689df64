//! The only place where micrometres meet the controller's millimetres.
//!
//! micropos speaks µm everywhere; GCS speaks mm (positions, travel limits)
//! and mm/s (velocity). Converting here, and only here, keeps a factor of
//! 1000 from going missing in between.

/// Micrometres per millimetre.
pub const UM_PER_MM: f64 = 1000.0;

/// µm (or µm/s) to the controller's mm (or mm/s).
pub fn um_to_mm(um: f64) -> f64 {
    um / UM_PER_MM
}

/// The controller's mm (or mm/s) to µm (or µm/s).
pub fn mm_to_um(mm: f64) -> f64 {
    mm * UM_PER_MM
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcs::command::format_number;
    use proptest::prelude::*;

    #[test]
    fn fixed_points() {
        assert_eq!(um_to_mm(1500.0), 1.5);
        assert_eq!(mm_to_um(15.0), 15_000.0);
        assert_eq!(format_number(um_to_mm(0.1)), "0.0001");
    }

    proptest! {
        /// A target in µm survives the trip to GCS text (7 decimals of mm)
        /// and back within 0.05 nm.
        #[test]
        fn round_trip_through_gcs_text(um in -1.0e6f64..1.0e6) {
            let text = format_number(um_to_mm(um));
            let back = mm_to_um(text.parse::<f64>().unwrap());
            prop_assert!((back - um).abs() <= 5e-5 + 1e-9 * um.abs());
        }
    }
}

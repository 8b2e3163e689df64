//! GCS 2.0 protocol core (sans-IO).

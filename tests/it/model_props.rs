//! Property tests for the numeric invariants of the stage model.

use micropos::model::terms::{play_offset_um, PlayOperator};
use micropos::model::{
    AxisMotion, Direction, FitOptions, MotionState, MotionTracker, Sample, StageModel,
    StageSimulator, Stochastic, Waypoint, MAX_PARAM_MAGNITUDE, MAX_POSITION_UM, MAX_TEMP_C,
    PAPER_DEFAULT_TOML,
};
use proptest::prelude::*;

fn direction() -> impl Strategy<Value = Direction> {
    prop_oneof![
        Just(Direction::Forward),
        Just(Direction::Backward),
        Just(Direction::Unknown)
    ]
}

fn axis_motion() -> impl Strategy<Value = AxisMotion> {
    (
        -MAX_POSITION_UM..MAX_POSITION_UM,
        direction(),
        0.0..1e6f64,
        proptest::option::of(0.0..1e6f64),
        0.0..1e6f64,
    )
        .prop_map(
            |(cmd_um, dir, run_um, prev_run_um, last_move_um)| AxisMotion {
                cmd_um,
                dir,
                run_um,
                prev_run_um,
                last_move_um,
            },
        )
}

fn state() -> impl Strategy<Value = MotionState> {
    (
        axis_motion(),
        axis_motion(),
        0.0..1e6f64,
        -273.15..MAX_TEMP_C,
        0u32..100,
    )
        .prop_map(|(x, y, time_s, temp_c, cycle)| MotionState {
            axes: [x, y],
            time_s,
            temp_c,
            cycle,
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// The play operator never lets the platform be more than B/2 from the
    /// screw, and the stateless model equals it whenever the history it
    /// forgets could not matter (the run before the previous one, or the
    /// previous one, took up the whole play); otherwise it is within B.
    #[test]
    fn play_stays_within_half_the_play(
        b in 0.0..5.0f64,
        moves in proptest::collection::vec(-6.0..6.0f64, 1..60),
    ) {
        let mut op = PlayOperator::new(b);
        let mut tracker = MotionTracker::new(MotionState::at_rest(0.0, 0.0)).unwrap();
        // Start with a long run so both begin from a known state.
        let mut x = -100.0;
        op.step(x);
        tracker.step(Waypoint::at(x, 0.0)).unwrap();
        let mut runs: Vec<f64> = vec![100.0];
        let mut last_sign = -1.0;
        for d in moves {
            if d == 0.0 {
                continue;
            }
            x += d;
            let exact = op.step(d);
            let st = tracker.step(Waypoint::at(x, 0.0)).unwrap();
            let sign = d.signum();
            if sign == last_sign {
                if let Some(r) = runs.last_mut() {
                    *r += d.abs();
                }
            } else {
                runs.push(d.abs());
                last_sign = sign;
            }
            let model = play_offset_um(&st.axes[0], b);
            prop_assert!(exact.abs() <= b / 2.0 + 1e-12);
            prop_assert!(model.abs() <= b / 2.0 + 1e-12);
            let k = runs.len() - 1;
            let knowable = k < 2 || runs[k - 1] >= b || runs[k - 2] >= b;
            if knowable {
                prop_assert!((model - exact).abs() < 1e-9, "model {} exact {} runs {:?}", model, exact, runs);
            } else {
                prop_assert!((model - exact).abs() <= b + 1e-12);
            }
        }
    }

    /// The tracker's last-move length is the length of the last move that
    /// happened (moves below the minimum incremental motion do not), never
    /// more than the run since the reversal, and 0 only before any motion.
    #[test]
    fn last_move_is_the_last_real_move_and_within_the_run(
        min_move in 0.0..0.5f64,
        moves in proptest::collection::vec((-50.0..50.0f64, -50.0..50.0f64), 1..40),
    ) {
        let mut tracker = MotionTracker::new(MotionState::at_rest(0.0, 0.0))
            .unwrap()
            .with_min_move(min_move)
            .unwrap();
        let mut expected = [0.0f64; 2];
        for (dx, dy) in moves {
            let before = *tracker.state();
            let target = [before.axes[0].cmd_um + dx, before.axes[1].cmd_um + dy];
            let st = tracker.step(Waypoint::at(target[0], target[1])).unwrap();
            for (a, want) in expected.iter_mut().enumerate() {
                let (ax, prev) = (&st.axes[a], &before.axes[a]);
                if ax.cmd_um != prev.cmd_um {
                    *want = (ax.cmd_um - prev.cmd_um).abs();
                }
                prop_assert_eq!(ax.last_move_um, *want);
                if ax.dir == Direction::Unknown {
                    prop_assert_eq!(ax.last_move_um, 0.0);
                } else {
                    prop_assert!(ax.last_move_um > 0.0);
                    prop_assert!(ax.last_move_um <= ax.run_um + 1e-9 * ax.run_um);
                }
            }
        }
    }

    /// Every contribution and jacobian entry of the default model is finite
    /// for any finite, valid state.
    #[test]
    fn default_model_is_finite_everywhere(s in state()) {
        let m = StageModel::paper_default().unwrap();
        prop_assert!(s.validate().is_ok());
        let t = m.true_position(&s);
        let o = m.observed_position(&s);
        prop_assert!(t.x_um.is_finite() && t.y_um.is_finite());
        prop_assert!(o.x_um.is_finite() && o.y_um.is_finite());
        for d in m.jacobian(&s) {
            prop_assert!(d[0].is_finite() && d[1].is_finite());
        }
    }

    /// Even with every parameter at an absurd but allowed magnitude, every
    /// valid state gives finite contributions.
    #[test]
    fn extreme_parameters_stay_finite(
        s in state(),
        scale in prop_oneof![Just(MAX_PARAM_MAGNITUDE), Just(-MAX_PARAM_MAGNITUDE), Just(1.0)],
        seed in any::<u64>(),
    ) {
        let mut m = StageModel::paper_default().unwrap();
        let n = m.param_count();
        let v: Vec<f64> = (0..n)
            .map(|i| if (seed >> (i % 64)) & 1 == 1 { scale } else { -scale })
            .collect();
        m.set_parameter_vector(&v).unwrap();
        let o = m.observed_position(&s);
        prop_assert!(o.x_um.is_finite() && o.y_um.is_finite());
        for d in m.jacobian(&s) {
            prop_assert!(d[0].is_finite() && d[1].is_finite());
        }
        let mut too_big = v.clone();
        too_big[seed as usize % n] = 2.0 * MAX_PARAM_MAGNITUDE;
        prop_assert!(m.set_parameter_vector(&too_big).is_err());
    }

    /// The simulator accepts any finite sequence without panicking and
    /// keeps its outputs finite.
    #[test]
    fn simulator_never_panics(
        targets in proptest::collection::vec((-2e4..2e4f64, -2e4..2e4f64), 1..40),
        seed in any::<u64>(),
    ) {
        let m = StageModel::paper_default().unwrap();
        let mut sim = StageSimulator::new(m, MotionState::at_rest(7500.0, 7500.0), seed).unwrap();
        for (i, (x, y)) in targets.into_iter().enumerate() {
            let s = sim.move_to(x, y, i as f64 * 10.0, 0).unwrap();
            prop_assert!(s.true_um.x_um.is_finite() && s.observed_um.y_um.is_finite());
            prop_assert!(s.state.axes[0].run_um >= 0.0 && s.state.axes[1].run_um >= 0.0);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    /// Noise-free data made by a model with random linear parameters is
    /// fitted back to those parameters and to zero residual.
    #[test]
    fn fit_of_noise_free_data_reproduces_it(
        deltas in proptest::collection::vec(-1.0..1.0f64, 45),
        sq in -3000.0..3000.0f64,
    ) {
        let mut truth = StageModel::paper_default().unwrap();
        truth.set_stochastic(Stochastic::default()).unwrap();
        let free = ["*_cyclic.*", "*_coupling.*", "squareness.*", "*_lead.*"];
        let names: Vec<String> = truth
            .params()
            .into_iter()
            .filter(|p| p.term.ends_with("_cyclic") || p.term.ends_with("_coupling") || p.term.ends_with("_lead"))
            .map(|p| p.full_name)
            .collect();
        for (n, d) in names.iter().zip(&deltas) {
            let v = truth.param(n).unwrap();
            let scale = if n.ends_with(".ppm") { 200.0 } else { 1.0 };
            truth.set_param(n, v + d * scale).unwrap();
        }
        truth.set_param("squareness.angle_urad", sq).unwrap();
        // Lines along x at two y and along y at two x, both directions.
        let mut wps = Vec::new();
        for fixed in [500.0, 2500.0] {
            for i in 0..=60 { wps.push(Waypoint::at(20.0 * i as f64 + 3.0, fixed)); }
            for i in (0..=60).rev() { wps.push(Waypoint::at(20.0 * i as f64 + 3.0, fixed)); }
        }
        for fixed in [500.0, 2500.0] {
            for i in 0..=60 { wps.push(Waypoint::at(fixed, 20.0 * i as f64 + 7.0)); }
            for i in (0..=60).rev() { wps.push(Waypoint::at(fixed, 20.0 * i as f64 + 7.0)); }
        }
        let states = MotionTracker::states_for(MotionState::at_rest(0.0, 0.0), &wps).unwrap();
        let samples: Vec<Sample> = states.iter().map(|s| {
            let o = truth.observed_position(s);
            Sample { state: *s, measured_x_um: o.x_um, measured_y_um: o.y_um }
        }).collect();
        let mut model = StageModel::paper_default().unwrap();
        let report = model.fit(&samples, &FitOptions::free(free)).unwrap();
        prop_assert!(report.linear);
        prop_assert!(report.unidentifiable.is_empty(), "{:?}", report.unidentifiable);
        prop_assert!(report.residual_rms_um[0] < 1e-8 && report.residual_rms_um[1] < 1e-8);
        for (a, b) in model.parameter_vector().iter().zip(truth.parameter_vector()) {
            prop_assert!((a - b).abs() < 1e-6 * (1.0 + b.abs()), "{} vs {}", a, b);
        }
    }

    /// Arbitrary text never panics the loader.
    #[test]
    fn loader_never_panics_on_garbage(text in ".{0,400}") {
        let _ = StageModel::from_toml(&text);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Replacing any number in the default file with something odd either
    /// loads a model with finite parameters or fails with an error; never a
    /// panic, never a NaN inside.
    #[test]
    fn loader_survives_odd_numbers(
        which in 0usize..200,
        odd in prop_oneof![
            Just("nan"), Just("inf"), Just("-inf"), Just("-1.0"), Just("0"),
            Just("1e308"), Just("\"x\""), Just("[]"), Just("{}"), Just("true")
        ],
    ) {
        // Numbers in the file, outside comments.
        let mut spans = Vec::new();
        for (ln, line) in PAPER_DEFAULT_TOML.lines().enumerate() {
            let code = line.split('#').next().unwrap_or("");
            let bytes = code.as_bytes();
            let mut i = 0;
            while i < bytes.len() {
                if bytes[i].is_ascii_digit() || (bytes[i] == b'-' && i + 1 < bytes.len() && bytes[i + 1].is_ascii_digit()) {
                    let start = i;
                    i += 1;
                    while i < bytes.len() && (bytes[i].is_ascii_digit() || bytes[i] == b'.' || bytes[i] == b'e') {
                        i += 1;
                    }
                    // Skip digits inside identifiers like `x_um` or strings.
                    let prev = if start == 0 { b' ' } else { bytes[start - 1] };
                    if prev == b' ' || prev == b'[' || prev == b'=' || prev == b',' {
                        spans.push((ln, start, i));
                    }
                } else {
                    i += 1;
                }
            }
        }
        prop_assume!(!spans.is_empty());
        let (ln, a, b) = spans[which % spans.len()];
        let text: String = PAPER_DEFAULT_TOML
            .lines()
            .enumerate()
            .map(|(i, l)| if i == ln { format!("{}{}{}", &l[..a], odd, &l[b..]) } else { l.to_string() })
            .collect::<Vec<_>>()
            .join("\n");
        match StageModel::from_toml(&text) {
            Ok(m) => {
                for p in m.parameter_vector() {
                    prop_assert!(p.is_finite());
                }
                for s in m.stochastic().repeatability_sigma_um {
                    prop_assert!(s.is_finite() && s >= 0.0);
                }
            }
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    }
}

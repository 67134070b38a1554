use super::*;

#[test]
fn the_period_is_a_whole_number_of_servo_periods_at_most_100_hz() {
    // 1000 Hz: every 10th tick; 250 Hz: every 3rd (83.3 Hz); 100 Hz and slower: every tick.
    let cases = [
        (1000.0, 0.010),
        (10000.0, 0.010),
        (250.0, 0.012),
        (333.0, 4.0 / 333.0),
        (100.0, 0.010),
        (50.0, 0.020),
    ];
    for (rate, seconds) in cases {
        let period = publish_period(rate).unwrap().as_secs_f64();
        assert!((period - seconds).abs() < 1e-9, "{rate} Hz: {period} s");
    }
}

#[test]
fn a_rate_that_is_not_positive_and_finite_is_refused() {
    for rate in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let error = publish_period(rate).unwrap_err();
        assert!(
            error.to_string().contains("not a positive finite"),
            "{error}"
        );
    }
}

//! A tangent direction named for people: translation, rotation, or a coupling of both
//! (`scanreg.quality.describe_direction` gives the same text).

/// Two decimals, no negative zero (`-0.001` reads `0.00`).
fn fmt2(x: f64) -> String {
    let s = format!("{x:.2}");
    if s == "-0.00" {
        "0.00".to_string()
    } else {
        s
    }
}

fn norm(v: &[f64]) -> f64 {
    let mut s = 0.0;
    for x in v {
        s += x * x;
    }
    s.sqrt()
}

fn list(v: &[f64], sign: f64, den: f64) -> String {
    let parts: Vec<String> = v.iter().map(|x| fmt2(sign * x / den)).collect();
    format!("({})", parts.join(", "))
}

/// Name the tangent direction `vector` (translation first) of a `dim`-D pose; rotations are
/// compared with translations in metres at `length_scale`. The sign is canonical: the largest
/// component of the leading part (the first of equals) reads positive.
pub fn describe(vector: &[f64], dim: usize, length_scale: f64) -> String {
    let (trans, rot) = vector.split_at(dim);
    let t_norm = norm(trans);
    let rot_norm = norm(rot);
    let r_norm = rot_norm * length_scale;
    let total = (t_norm + r_norm).max(1e-300);
    let lead = if t_norm >= r_norm { trans } else { rot };
    let mut largest = 0;
    for i in 1..lead.len() {
        if lead[i].abs() > lead[largest].abs() {
            largest = i;
        }
    }
    let sign = if lead[largest] < 0.0 { -1.0 } else { 1.0 };
    let t_txt = format!(
        "translation along {}",
        list(trans, sign, t_norm.max(1e-300))
    );
    let r_txt = if dim == 2 {
        "rotation (θ)".to_string()
    } else {
        format!("rotation about {}", list(rot, sign, rot_norm.max(1e-300)))
    };
    if r_norm / total < 0.1 {
        return t_txt;
    }
    if t_norm / total < 0.1 {
        return r_txt;
    }
    let (first, second) = if t_norm >= r_norm {
        (t_txt, r_txt)
    } else {
        (r_txt, t_txt)
    };
    format!("{first} coupled with {second}")
}

#[cfg(test)]
mod tests {
    use super::describe;

    #[test]
    fn names_translation_rotation_and_couplings() {
        assert_eq!(
            describe(&[-1.0, 0.0, 0.0], 2, 1.0),
            "translation along (1.00, 0.00)"
        );
        assert_eq!(describe(&[0.0, 0.001, 1.0], 2, 1.0), "rotation (θ)");
        assert_eq!(
            describe(&[0.0, 0.0, 0.0, 0.0, 0.0, -1.0], 3, 2.0),
            "rotation about (0.00, 0.00, 1.00)"
        );
        assert_eq!(
            describe(&[0.6, 0.0, 0.8], 2, 1.0),
            "rotation (θ) coupled with translation along (1.00, 0.00)"
        );
    }
}

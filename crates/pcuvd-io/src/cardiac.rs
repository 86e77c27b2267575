//! Cardiac references recorded beside the ultrasound: the start times of cardiac cycles (ECG
//! R-waves, scanner trigger times), which delimit the cycles of the dynamics stage.

use std::path::Path;

use ndarray::Array1;
use ndarray_npy::ReadNpyExt;

use crate::error::IoError;

/// `[cardiac]` of a manifest (a recording's or an images manifest): the cardiac cycles recorded
/// beside the ultrasound, for the dynamics stage.
#[derive(Debug, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CardiacSection {
    /// Cycle start times (s from the first frame): ECG R-waves or scanner triggers.
    pub(crate) triggers_s: Option<Vec<f64>>,
    /// A 1-D `.npy` or text file of such times, relative to the manifest's folder.
    pub(crate) triggers_file: Option<String>,
}

/// The cycle start times of the manifest `path`'s `[cardiac]` table (inline or from its file),
/// checked; `None` without the table.
pub(crate) fn triggers_of_section(
    path: &Path,
    cardiac: Option<CardiacSection>,
) -> Result<Option<Vec<f64>>, IoError> {
    let Some(c) = cardiac else {
        return Ok(None);
    };
    match (c.triggers_s, c.triggers_file) {
        (Some(times), None) => {
            check_times_of(path, "[cardiac].triggers_s", &times)?;
            Ok(Some(times))
        }
        (None, Some(file)) => {
            let file = path.parent().unwrap_or(Path::new("")).join(file);
            read_trigger_times(&file)
                .map(Some)
                .map_err(|e| IoError::invalid(path, "[cardiac].triggers_file", format!("{e}")))
        }
        (Some(_), Some(_)) => Err(IoError::invalid(
            path,
            "[cardiac]",
            "give triggers_s or triggers_file, not both",
        )),
        (None, None) => Err(IoError::missing(
            path,
            "table [cardiac]",
            "key 'triggers_s' or 'triggers_file'",
        )),
    }
}

/// Reads cardiac cycle start times (s, from the recording's first frame) from a 1-D `.npy` file
/// (float64, float32 or integer) or a text file of numbers separated by commas, spaces or new
/// lines (`#` starts a comment). The times must be finite and strictly increasing.
pub fn read_trigger_times(path: &Path) -> Result<Vec<f64>, IoError> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    let times = if is_npy {
        read_npy_times(path)?
    } else {
        let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, "read", e))?;
        parse_times(path, &text)?
    };
    check_times(path, &times)?;
    Ok(times)
}

fn read_npy_times(path: &Path) -> Result<Vec<f64>, IoError> {
    let open = || std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e));
    if let Ok(a) = Array1::<f64>::read_npy(open()?) {
        return Ok(a.to_vec());
    }
    if let Ok(a) = Array1::<f32>::read_npy(open()?) {
        return Ok(a.iter().map(|&v| f64::from(v)).collect());
    }
    if let Ok(a) = Array1::<i64>::read_npy(open()?) {
        return Ok(a.iter().map(|&v| v as f64).collect());
    }
    Array1::<i32>::read_npy(open()?)
        .map(|a| a.iter().map(|&v| f64::from(v)).collect())
        .map_err(|e| {
            IoError::malformed(
                path,
                format!("expected a 1-D array of times in s (float64, float32 or integer): {e}"),
            )
        })
}

fn parse_times(path: &Path, text: &str) -> Result<Vec<f64>, IoError> {
    let mut times = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for word in line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|w| !w.is_empty())
        {
            let value = word.parse::<f64>().map_err(|_| {
                IoError::malformed(
                    path,
                    format!(
                        "line {}: {word:?} is not a number (expected times in s)",
                        line_no + 1
                    ),
                )
            })?;
            times.push(value);
        }
    }
    Ok(times)
}

fn check_times(path: &Path, times: &[f64]) -> Result<(), IoError> {
    check_times_of(path, "the trigger times", times)
}

/// Checks cycle start times (s) named `key` in `path`: at least two, finite, increasing.
pub(crate) fn check_times_of(path: &Path, key: &str, times: &[f64]) -> Result<(), IoError> {
    if times.len() < 2 {
        return Err(IoError::invalid(
            path,
            key,
            format!(
                "hold {} time(s); at least two are needed for one cardiac cycle",
                times.len()
            ),
        ));
    }
    if let Some(i) = times.iter().position(|t| !t.is_finite()) {
        return Err(IoError::invalid(
            path,
            key,
            format!("time {i} is {}: every time must be finite", times[i]),
        ));
    }
    if let Some(i) = times.windows(2).position(|w| w[1] <= w[0]) {
        return Err(IoError::invalid(
            path,
            key,
            format!(
                "must increase: time {} is {} s, time {} is {} s",
                i,
                times[i],
                i + 1,
                times[i + 1]
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_and_npy_give_the_same_times() {
        let dir = tempfile::tempdir().unwrap();
        let text = dir.path().join("triggers.txt");
        std::fs::write(&text, "# R-waves (s)\n0.012, 0.193\n0.375 0.556\n").unwrap();
        let npy = dir.path().join("triggers.npy");
        ndarray_npy::write_npy(&npy, &Array1::from(vec![0.012f64, 0.193, 0.375, 0.556])).unwrap();
        let expected = vec![0.012, 0.193, 0.375, 0.556];
        assert_eq!(read_trigger_times(&text).unwrap(), expected);
        assert_eq!(read_trigger_times(&npy).unwrap(), expected);
    }

    #[test]
    fn bad_times_name_the_problem() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("one.txt", "0.1\n", "at least two"),
            ("word.txt", "0.1, abc\n", "line 1: \"abc\" is not a number"),
            ("back.txt", "0.2 0.1\n", "must increase"),
            ("nan.txt", "0.1 nan\n", "must be finite"),
        ];
        for (name, text, expected) in cases {
            let path = dir.path().join(name);
            std::fs::write(&path, text).unwrap();
            let message = read_trigger_times(&path).unwrap_err().to_string();
            assert!(message.contains(expected), "{name}: {message}");
            assert!(message.contains(name), "{name}: {message}");
        }
    }
}

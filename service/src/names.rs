//! The names users give: a job's name and its assets' names, checked before anything is
//! stored. Names are shown in lists and become a download's file name; they never name a
//! file on the service's disk.

use crate::error::ApiError;

/// Longest job or asset name, in bytes (a file name's usual limit: a job's name becomes the
/// download's file name).
pub const MAX_NAME: usize = 255;

/// A job's name (`name=`, or the uploaded scene's file name) is shown in every job list and
/// page: at most [`MAX_NAME`] bytes and no control characters.
pub fn check_job_name(name: &str) -> Result<(), ApiError> {
    if name.len() > MAX_NAME {
        return Err(ApiError::bad_request(format!(
            "the job name is {} bytes long; at most {MAX_NAME} are allowed",
            name.len()
        )));
    }
    if name.chars().any(char::is_control) {
        return Err(ApiError::bad_request(
            "the job name may not hold control characters (line breaks, tabs …)",
        ));
    }
    Ok(())
}

/// Asset names are names, not paths: relative, `/`-separated, no `.` or `..` segments, no
/// backslashes or control characters. Nothing ever resolves them on a file system anyway.
pub fn check_asset_name(name: &str) -> Result<(), ApiError> {
    let bad = name.is_empty()
        || name.len() > MAX_NAME
        || name.starts_with('/')
        || name.contains('\\')
        || name.chars().any(char::is_control)
        || name
            .split('/')
            .any(|seg| seg.is_empty() || seg == "." || seg == "..");
    if bad {
        return Err(ApiError::bad_request(format!(
            "`{name}` is not a valid asset name: use the relative file name the scene uses, \
             without `..` or a leading `/`"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::check_asset_name;

    #[test]
    fn asset_names_cannot_be_paths_out() {
        for bad in [
            "",
            "/etc/passwd",
            "../x.png",
            "a/../../b",
            "a\\b",
            "./a",
            "a//b",
            "x\u{0}",
        ] {
            assert!(check_asset_name(bad).is_err(), "{bad:?}");
        }
        for good in ["globe.png", "textures/globe.png", "a b.ppm"] {
            assert!(check_asset_name(good).is_ok(), "{good:?}");
        }
    }
}

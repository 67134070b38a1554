//! The control token check: REST control requests carry `Authorization: Bearer TOKEN`, WebSocket control
//! messages a `"token"` field. Reading state needs no token.
//!
//! The comparison takes the same time wherever the first differing byte is, so the token cannot be guessed
//! a byte at a time from response times (only its length could leak, and every generated token has 32).

use axum::http::{header::AUTHORIZATION, HeaderMap};

/// Why a control request was refused (HTTP 401).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AuthError {
    #[error("unauthorized: control requests need the header `Authorization: Bearer TOKEN` (the token `voxhap serve` printed)")]
    Missing,
    #[error("unauthorized: the Authorization header must be `Bearer TOKEN`")]
    Malformed,
    #[error("unauthorized: wrong token")]
    Wrong,
}

/// True when `given` equals `expected`, in time independent of where they differ.
pub fn token_matches(expected: &str, given: &str) -> bool {
    let (expected, given) = (expected.as_bytes(), given.as_bytes());
    if expected.len() != given.len() {
        return false;
    }
    let difference = expected
        .iter()
        .zip(given)
        .fold(0u8, |acc, (a, b)| acc | (a ^ b));
    std::hint::black_box(difference) == 0
}

/// Checks a WebSocket control message's token.
pub fn check_token(expected: &str, given: Option<&str>) -> Result<(), AuthError> {
    match given {
        None => Err(AuthError::Missing),
        Some(given) if token_matches(expected, given) => Ok(()),
        Some(_) => Err(AuthError::Wrong),
    }
}

/// Checks the `Authorization: Bearer TOKEN` header of a REST control request.
pub fn check_bearer(expected: &str, headers: &HeaderMap) -> Result<(), AuthError> {
    let Some(value) = headers.get(AUTHORIZATION) else {
        return Err(AuthError::Missing);
    };
    let value = value.to_str().map_err(|_| AuthError::Malformed)?;
    let (scheme, token) = value.split_once(' ').ok_or(AuthError::Malformed)?;
    if !scheme.eq_ignore_ascii_case("bearer") {
        return Err(AuthError::Malformed);
    }
    check_token(expected, Some(token.trim()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    #[test]
    fn only_the_exact_token_passes() {
        assert!(token_matches("abcdef0123", "abcdef0123"));
        assert!(!token_matches("abcdef0123", "abcdef0124"));
        assert!(!token_matches("abcdef0123", "abcdef012"));
        assert!(!token_matches("abcdef0123", ""));
        assert_eq!(check_token("abcdef0123", None), Err(AuthError::Missing));
    }

    #[test]
    fn bearer_headers() {
        let mut headers = HeaderMap::new();
        assert_eq!(check_bearer("tok12345", &headers), Err(AuthError::Missing));
        headers.insert(AUTHORIZATION, HeaderValue::from_static("Bearer tok12345"));
        assert_eq!(check_bearer("tok12345", &headers), Ok(()));
        headers.insert(AUTHORIZATION, HeaderValue::from_static("bearer tok12345"));
        assert_eq!(check_bearer("tok12345", &headers), Ok(()));
        headers.insert(AUTHORIZATION, HeaderValue::from_static("Bearer nope"));
        assert_eq!(check_bearer("tok12345", &headers), Err(AuthError::Wrong));
        headers.insert(AUTHORIZATION, HeaderValue::from_static("Basic tok12345"));
        assert_eq!(
            check_bearer("tok12345", &headers),
            Err(AuthError::Malformed)
        );
        headers.insert(AUTHORIZATION, HeaderValue::from_static("tok12345"));
        assert_eq!(
            check_bearer("tok12345", &headers),
            Err(AuthError::Malformed)
        );
    }
}

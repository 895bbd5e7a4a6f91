//! Bearer tokens on every RPC: the server side refuses calls without the
//! configured token, the client side attaches it.

use tonic::metadata::MetadataValue;
use tonic::{Request, Status};

/// Where a token may come from, in order: the flag, the environment
/// variable `SYLVA_TOKEN`, a file (trailing whitespace trimmed).
pub fn load_token(flag: Option<&str>, file: Option<&std::path::Path>) -> std::io::Result<Option<String>> {
    if let Some(t) = flag.filter(|t| !t.is_empty()) {
        return Ok(Some(t.to_string()));
    }
    if let Ok(t) = std::env::var("SYLVA_TOKEN")
        && !t.is_empty() {
            return Ok(Some(t));
        }
    match file {
        Some(p) => Ok(Some(std::fs::read_to_string(p)?.trim_end().to_string()).filter(|t| !t.is_empty())),
        None => Ok(None),
    }
}

/// A server interceptor: with a token configured, calls must carry
/// `authorization: Bearer <token>`; UNAUTHENTICATED otherwise.
pub fn require(token: Option<String>) -> impl FnMut(Request<()>) -> Result<Request<()>, Status> + Clone {
    move |req: Request<()>| {
        let Some(want) = &token else { return Ok(req) };
        let got = req.metadata().get("authorization").and_then(|v| v.to_str().ok()).and_then(|v| v.strip_prefix("Bearer "));
        match got {
            Some(g) if constant_time_eq(g.as_bytes(), want.as_bytes()) => Ok(req),
            Some(_) => Err(Status::unauthenticated("wrong bearer token")),
            None => Err(Status::unauthenticated("this service needs a bearer token (authorization: Bearer …)")),
        }
    }
}

/// A client interceptor that attaches `token`, if any.
pub fn attach(token: Option<String>) -> impl FnMut(Request<()>) -> Result<Request<()>, Status> + Clone {
    let value: Option<MetadataValue<_>> = token.and_then(|t| format!("Bearer {t}").parse().ok());
    move |mut req: Request<()>| {
        if let Some(v) = &value {
            req.metadata_mut().insert("authorization", v.clone());
        }
        Ok(req)
    }
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_checked() {
        let mut check = require(Some("s3cret".into()));
        let mut add = attach(Some("s3cret".into()));
        assert!(check(add(Request::new(())).unwrap()).is_ok());
        assert_eq!(check(Request::new(())).unwrap_err().code(), tonic::Code::Unauthenticated);
        let mut wrong = attach(Some("guess".into()));
        assert_eq!(check(wrong(Request::new(())).unwrap()).unwrap_err().code(), tonic::Code::Unauthenticated);
        let mut open = require(None);
        assert!(open(Request::new(())).is_ok());
    }
}

//! Bearer tokens on every RPC: the client side attaches it, the server
//! side reads it back (each service checks it against its own tokens).

use tonic::metadata::MetadataValue;
use tonic::{Request, Status};

/// Where a token may come from, in order: the flag, the environment
/// variable `SYLVA_TOKEN`, a file (trailing whitespace trimmed).
pub fn load_token(
    flag: Option<&str>,
    file: Option<&std::path::Path>,
) -> std::io::Result<Option<String>> {
    let token = if let Some(t) = flag.filter(|t| !t.is_empty()) {
        Some(t.to_string())
    } else if let Ok(t) = std::env::var("SYLVA_TOKEN")
        && !t.is_empty()
    {
        Some(t)
    } else {
        match file {
            Some(p) => {
                Some(std::fs::read_to_string(p)?.trim_end().to_string()).filter(|t| !t.is_empty())
            }
            None => None,
        }
    };
    // A token travels as an HTTP header value: one that cannot would be
    // dropped from every call, and the server would say none was sent.
    if let Some(t) = &token
        && !t.bytes().all(|b| b.is_ascii_graphic())
    {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "the token must be printable ASCII without spaces (it travels as an HTTP header)",
        ));
    }
    Ok(token)
}

/// A client interceptor that attaches a bearer token, if any.
#[derive(Clone, Debug)]
pub struct Attach(Option<MetadataValue<tonic::metadata::Ascii>>);

impl tonic::service::Interceptor for Attach {
    fn call(&mut self, mut req: Request<()>) -> Result<Request<()>, Status> {
        if let Some(v) = &self.0 {
            req.metadata_mut().insert("authorization", v.clone());
        }
        Ok(req)
    }
}

/// A client interceptor that attaches `token`, if any.
pub fn attach(token: Option<String>) -> Attach {
    Attach(token.and_then(|t| format!("Bearer {t}").parse().ok()))
}

/// The bearer token a request carries, if any.
pub fn bearer_of<T>(req: &Request<T>) -> Option<&str> {
    req.metadata().get("authorization").and_then(|v| v.to_str().ok()).and_then(bearer)
}

/// The token of an `authorization` value: the scheme is case-insensitive
/// (RFC 7235), surrounding spaces are ignored.
pub fn bearer(value: &str) -> Option<&str> {
    let (scheme, token) = value.trim().split_once(' ')?;
    scheme.eq_ignore_ascii_case("bearer").then(|| token.trim())
}

/// `n` bytes from the operating system's random source, in hex.
pub fn random_hex(n: usize) -> String {
    random_bytes(n).iter().map(|b| format!("{b:02x}")).collect()
}

/// `n` bytes from the operating system's random source.
pub fn random_bytes(n: usize) -> Vec<u8> {
    let mut b = vec![0u8; n];
    getrandom::getrandom(&mut b).expect("the operating system's random source");
    b
}

/// The registrations a worker sent lately, by their random claims: the
/// worker answers an identity check only for one of them, so a
/// coordinator hands a session key only to the worker at the address a
/// registration names (see `RegisterWorkerRequest.claim`).
#[derive(Clone, Debug, Default)]
pub struct Claims(std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<Vec<u8>>>>);

impl Claims {
    /// Registrations whose claims are kept: a few periods' worth.
    const KEPT: usize = 8;

    /// A new claim for a registration about to be sent.
    pub fn fresh(&self) -> Vec<u8> {
        let c = random_bytes(32);
        let mut q = crate::sync::lock(&self.0);
        if q.len() >= Self::KEPT {
            q.pop_front();
        }
        q.push_back(c.clone());
        c
    }

    /// Whether `claim` is one of this worker's recent registrations.
    pub fn holds(&self, claim: &[u8]) -> bool {
        claim.len() == 32 && crate::sync::lock(&self.0).iter().any(|c| constant_time_eq(c, claim))
    }
}

/// A fresh random token (256 bits) for processes only their starter talks to.
pub fn random_token() -> String {
    random_hex(32)
}

/// Argon2id's cost for a proof key: OWASP's minimum for passwords (19 MiB,
/// two passes, one lane), so each guess at a human-chosen token costs as
/// much as a password guess does.
pub const PROOF_KDF: (u32, u32, u32) = (19 * 1024, 2, 1);

/// Bytes of a proof's salt.
pub const PROOF_SALT: usize = 16;

/// The key a proof is made with: Argon2id of the token and `salt`.
fn proof_key(token: Option<&str>, salt: &[u8]) -> [u8; 32] {
    let (m, t, p) = PROOF_KDF;
    let params = argon2::Params::new(m, t, p, Some(32)).expect("valid Argon2 parameters");
    let kdf = argon2::Argon2::new(argon2::Algorithm::Argon2id, argon2::Version::V0x13, params);
    let mut key = [0u8; 32];
    kdf.hash_password_into(token.unwrap_or("").as_bytes(), salt, &mut key)
        .expect("a 16-byte salt and a 32-byte key are within Argon2's bounds");
    key
}

/// A worker's proof that it holds `token`, for the coordinator's `nonce`:
/// a fresh salt, and BLAKE3 of the nonce keyed by Argon2id(token, salt).
/// Whoever asks learns nothing cheaper to test a guess against than a slow
/// key derivation per guess, and the proof cannot be replayed for another
/// nonce.
pub fn prove(token: Option<&str>, nonce: &[u8]) -> (Vec<u8>, [u8; 32]) {
    let salt = random_bytes(PROOF_SALT);
    let proof = *blake3::keyed_hash(&proof_key(token, &salt), nonce).as_bytes();
    (salt, proof)
}

/// A user's token (`sylva_ID_SECRET`, 12 hex digits of id and 64 of
/// secret) split into its id and secret.
pub fn user_token(token: &str) -> Option<(&str, &str)> {
    let rest = token.strip_prefix("sylva_")?;
    let (id, secret) = rest.split_once('_')?;
    let hex = |s: &str, n: usize| s.len() == n && s.bytes().all(|b| b.is_ascii_hexdigit());
    (hex(id, 12) && hex(secret, 64)).then_some((id, secret))
}

/// The key a user token's record holds (its secret's keyed BLAKE3): what
/// the coordinator checks the token and its worker's proofs against.
pub fn user_token_key(secret: &str) -> [u8; 32] {
    blake3::derive_key("sylva 2026 user token v1", secret.as_bytes())
}

/// A proof with a user's token: BLAKE3 of `nonce` keyed by the token's key.
pub fn prove_with_key(key: &[u8; 32], nonce: &[u8]) -> [u8; 32] {
    *blake3::keyed_hash(key, nonce).as_bytes()
}

/// Whether `proof` with `salt` answers `nonce` for `token`, compared in constant time.
pub fn check_proof(token: Option<&str>, nonce: &[u8], salt: &[u8], proof: &[u8]) -> bool {
    salt.len() == PROOF_SALT
        && constant_time_eq(blake3::keyed_hash(&proof_key(token, salt), nonce).as_bytes(), proof)
}

/// Compares two byte strings in time that depends on their length only.
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_attached_and_read_back() {
        use tonic::service::Interceptor;
        let mut add = attach(Some("s3cret".into()));
        assert_eq!(bearer_of(&add.call(Request::new(())).unwrap()), Some("s3cret"));
        let mut none = attach(None);
        assert_eq!(bearer_of(&none.call(Request::new(())).unwrap()), None);
        for form in ["bearer s3cret", "BEARER s3cret", "  Bearer   s3cret "] {
            let mut r = Request::new(());
            r.metadata_mut().insert("authorization", form.parse().unwrap());
            assert_eq!(bearer_of(&r), Some("s3cret"), "{form:?}");
        }
        assert_eq!(bearer("Basic s3cret"), None);
    }

    #[test]
    fn proofs_match_only_the_same_token_and_nonce() {
        let (salt, p) = prove(Some("s3cret"), b"nonce-1");
        assert!(check_proof(Some("s3cret"), b"nonce-1", &salt, &p));
        assert!(!check_proof(Some("s3cret"), b"nonce-2", &salt, &p));
        assert!(!check_proof(Some("guess"), b"nonce-1", &salt, &p));
        assert!(!check_proof(None, b"nonce-1", &salt, &p));
        assert!(!check_proof(Some("s3cret"), b"nonce-1", &salt[..8], &p), "a short salt");
        // Salted afresh: the same question never gets the same answer.
        let (salt2, p2) = prove(Some("s3cret"), b"nonce-1");
        assert!(salt2 != salt && p2 != p);
        // Not the BLAKE3 key a guess list could be tried against cheaply.
        let fast = blake3::derive_key("sylva 2026 worker identity v1", b"s3cret");
        assert_ne!(*blake3::keyed_hash(&fast, b"nonce-1").as_bytes(), p);
        assert_ne!(random_token(), random_token());
        assert_eq!(random_token().len(), 64);
    }
}

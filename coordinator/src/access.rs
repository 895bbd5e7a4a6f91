//! Who may do what. Users hold tokens of their own, each with a role —
//! `admin` (everything), `submitter` (their own jobs, and reading the
//! farm) or `worker` (registering itself) — made by `sylva token add` on
//! the state folder and kept as hashes in the database. The coordinator's
//! `--token`, when given, is one more admin token (a one-person farm); with
//! neither, the farm is open and every caller is an admin.
//!
//! A user's token is `sylva_ID_SECRET`: a public id that finds its record
//! and 256 random bits whose BLAKE3 hash the record holds. A random secret
//! needs no slow hash; the id keeps the check one lookup and one compare.

use crate::store::TokenRow;
use std::collections::HashMap;
use std::sync::RwLock;
use sylva_proto::auth::constant_time_eq;
use sylva_proto::sync::{read, write};

/// What a caller may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Role {
    /// Everything: any job, every worker, the farm's settings.
    Admin,
    /// Submit, and act on their own jobs; read the farm.
    Submitter,
    /// Register itself as a worker; nothing else.
    Worker,
}

impl Role {
    /// Every role.
    pub const ALL: [Role; 3] = [Role::Admin, Role::Submitter, Role::Worker];

    /// Its name, as `sylva token add --role` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Role::Admin => "admin",
            Role::Submitter => "submitter",
            Role::Worker => "worker",
        }
    }

    /// The role a name names.
    pub fn from_name(name: &str) -> Option<Role> {
        Self::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// Who made a call: put in the request's extensions by the API's
/// interceptor, read by each call.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    /// The user ("" on an open farm, "admin" for the coordinator's `--token`).
    pub user: String,
    /// Their role.
    pub role: Role,
    /// The token's id ("" for the coordinator's `--token` or an open farm).
    pub token_id: String,
}

impl Caller {
    /// Whether this caller may act on a job `submitter` submitted.
    pub fn owns(&self, submitter: &str) -> bool {
        self.role == Role::Admin || (self.role == Role::Submitter && self.user == submitter)
    }
}

/// A token just made: the token, shown once, and its record.
pub struct Issued {
    /// `sylva_ID_SECRET`.
    pub token: String,
    /// What the database keeps.
    pub row: TokenRow,
}

/// A new token for `user` with `role`.
pub fn issue(user: &str, role: Role) -> Issued {
    let id = sylva_proto::auth::random_hex(6);
    let secret = sylva_proto::auth::random_hex(32);
    let row = TokenRow {
        id: id.clone(),
        user: user.to_string(),
        role: role.name().into(),
        hash: hash(&secret),
        created_ms: crate::store::now_ms() as u64,
        revoked_ms: 0,
    };
    Issued { token: format!("sylva_{id}_{secret}"), row }
}

/// A token's secret's key, hex: what the database keeps.
fn hash(secret: &str) -> String {
    sylva_proto::auth::user_token_key(secret).iter().map(|b| format!("{b:02x}")).collect()
}

/// Whether a user name may be given (and shown in listings as it is).
pub fn valid_user(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && name.chars().all(|c| c.is_ascii_alphanumeric() || "._-@".contains(c))
}

/// The tokens a coordinator accepts: its own `--token` and the users'
/// (a copy of the database's, refreshed as it changes).
#[derive(Debug, Default)]
pub struct Access {
    legacy: Option<String>,
    tokens: RwLock<HashMap<String, TokenRow>>,
    /// Whether the farm has ever had users: then it stays closed, even
    /// once every token is revoked.
    users: std::sync::atomic::AtomicBool,
}

impl Access {
    /// Access with the coordinator's own token, if any, and no users yet.
    pub fn new(legacy: Option<String>) -> Self {
        Self { legacy, ..Default::default() }
    }

    /// The users' tokens now (revoked ones are left out).
    pub fn set(&self, rows: Vec<TokenRow>) {
        if !rows.is_empty() {
            self.users.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        let live = rows.into_iter().filter(|r| r.revoked_ms == 0).map(|r| (r.id.clone(), r));
        *write(&self.tokens) = live.collect();
    }

    /// Whether callers must bring a token.
    pub fn closed(&self) -> bool {
        self.legacy.is_some() || self.users.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Who `bearer` makes a caller; `None` for a wrong or missing token on
    /// a closed farm.
    pub fn caller(&self, bearer: Option<&str>) -> Option<Caller> {
        if !self.closed() {
            return Some(Caller {
                user: String::new(),
                role: Role::Admin,
                token_id: String::new(),
            });
        }
        let bearer = bearer?;
        if let Some(want) = &self.legacy
            && constant_time_eq(bearer.as_bytes(), want.as_bytes())
        {
            return Some(Caller {
                user: "admin".into(),
                role: Role::Admin,
                token_id: String::new(),
            });
        }
        let (id, secret) = sylva_proto::auth::user_token(bearer)?;
        let tokens = read(&self.tokens);
        let row = tokens.get(id)?;
        if !constant_time_eq(hash(secret).as_bytes(), row.hash.as_bytes()) {
            return None;
        }
        Some(Caller {
            user: row.user.clone(),
            role: Role::from_name(&row.role)?,
            token_id: row.id.clone(),
        })
    }

    /// Whether the user token `id` is still live ("": the coordinator's own
    /// token or an open farm, which are not revoked).
    pub fn live(&self, id: &str) -> bool {
        id.is_empty() || read(&self.tokens).contains_key(id)
    }

    /// The key of a live user token, by id: what that token's worker
    /// proves its identity with.
    pub fn key_of(&self, id: &str) -> Option<[u8; 32]> {
        let tokens = read(&self.tokens);
        let hex = &tokens.get(id)?.hash;
        let mut key = [0u8; 32];
        for (i, k) in key.iter_mut().enumerate() {
            *k = u8::from_str_radix(hex.get(2 * i..2 * i + 2)?, 16).ok()?;
        }
        Some(key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_users_token_names_its_user_and_role_until_revoked() {
        let a = Access::new(None);
        assert_eq!(a.caller(None).map(|c| c.role), Some(Role::Admin), "an open farm");
        let alice = issue("alice", Role::Submitter);
        let mut row = alice.row.clone();
        a.set(vec![row.clone()]);
        assert!(a.closed() && a.caller(None).is_none());
        let c = a.caller(Some(&alice.token)).unwrap();
        assert_eq!((c.user.as_str(), c.role), ("alice", Role::Submitter));
        assert!(c.owns("alice") && !c.owns("bob"));
        // The database keeps the hash only; a changed secret is refused.
        assert!(!row.hash.contains(&alice.token[19..]));
        let mut forged = alice.token.clone();
        forged.replace_range(forged.len() - 1.., if forged.ends_with('0') { "1" } else { "0" });
        assert!(a.caller(Some(&forged)).is_none());
        row.revoked_ms = 1;
        a.set(vec![row]);
        assert!(a.caller(Some(&alice.token)).is_none(), "revoked");
        assert!(a.closed() && a.caller(None).is_none(), "revoking the last token opens nothing");
        let legacy = Access::new(Some("one-person".into()));
        assert_eq!(legacy.caller(Some("one-person")).unwrap().role, Role::Admin);
        assert!(legacy.caller(Some("guess")).is_none());
        assert!(valid_user("render.farm-1@studio") && !valid_user("a b") && !valid_user(""));
    }
}

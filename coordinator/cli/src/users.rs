//! `sylva token add|list|revoke` and `sylva audit`: the farm's users and
//! its audit log, read and written on the coordinator's database (the
//! operator's access to the state folder is what authorises them).

use crate::flags::users::*;
use sylva_coordinator::access::{self, Role};
use sylva_coordinator::store::{AuditRow, Store};

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_current_thread().enable_all().build()?)
}

fn when(ms: u64) -> String {
    if ms == 0 {
        return "-".into();
    }
    let s = ms / 1000;
    let (d, r) = (s / 86_400, s % 86_400);
    // Days since 1970 as a civil date (Howard Hinnant's algorithm).
    let z = d as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + (month <= 2) as i64;
    format!("{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}", r / 3600, r % 3600 / 60, r % 60)
}

pub fn run_token(c: TokenCommand) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        match c {
            TokenCommand::Add(a) => {
                anyhow::ensure!(
                    access::valid_user(&a.user),
                    "user name {:?}: 1 to 64 letters, digits, '.', '_', '-' or '@'",
                    sylva_scene::sandbox::clip(&a.user)
                );
                let role = Role::from_name(&a.role).expect("clap checked the role");
                let store = Store::open(&a.state.url()?).await?;
                // A second live token for a user is allowed (a new machine,
                // a rotation), but never unannounced: the old one still works.
                let live: Vec<String> = store
                    .tokens()
                    .await?
                    .into_iter()
                    .filter(|t| t.user == a.user && t.revoked_ms == 0)
                    .map(|t| t.id)
                    .collect();
                let issued = access::issue(&a.user, role);
                store.add_token(&issued.row).await?;
                store
                    .audit(&AuditRow::now(
                        "operator",
                        "token add",
                        &issued.row.id,
                        &format!("{} as {}", a.user, a.role),
                    ))
                    .await?;
                store.close().await;
                eprintln!(
                    "token {} for {} ({}): shown this once; the farm keeps only its hash",
                    issued.row.id, a.user, a.role
                );
                if !live.is_empty() {
                    eprintln!(
                        "{} also holds {} live token{} ({}), which still work{}: `sylva token \
                         revoke ID` ends one",
                        a.user,
                        live.len(),
                        if live.len() == 1 { "" } else { "s" },
                        live.join(", "),
                        if live.len() == 1 { "s" } else { "" },
                    );
                }
                println!("{}", issued.token);
            }
            TokenCommand::List(a) => {
                let store = Store::open(&a.state.url()?).await?;
                let rows = store.tokens().await?;
                store.close().await;
                print_rows(a.json, &rows, &["id", "user", "role", "created", "revoked"], |t| {
                    vec![
                        t.id.clone(),
                        t.user.clone(),
                        t.role.clone(),
                        when(t.created_ms),
                        when(t.revoked_ms),
                    ]
                })?;
            }
            TokenCommand::Revoke(a) => {
                let store = Store::open(&a.state.url()?).await?;
                let done = store.revoke_token(&a.id).await?;
                if done {
                    store.audit(&AuditRow::now("operator", "token revoke", &a.id, "")).await?;
                }
                store.close().await;
                anyhow::ensure!(done, "no live token {:?}", sylva_scene::sandbox::clip(&a.id));
                println!("revoked {}", a.id);
            }
        }
        Ok(())
    })
}

pub fn run_audit(a: AuditArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        let store = Store::open(&a.state.url()?).await?;
        let rows = store.audit_log(a.limit).await?;
        store.close().await;
        print_rows(a.json, &rows, &["when (UTC)", "who", "what", "on", "detail"], |r| {
            vec![
                when(r.at_ms),
                r.actor.clone(),
                r.action.clone(),
                r.target.clone(),
                r.detail.clone(),
            ]
        })
    })
}

/// Rows as JSON, or as a table of `header` with `cells` of each row.
fn print_rows<T: serde::Serialize>(
    json: bool,
    rows: &[T],
    header: &[&str],
    cells: impl Fn(&T) -> Vec<String>,
) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(rows)?);
    } else {
        let cells: Vec<Vec<String>> = rows.iter().map(cells).collect();
        print!("{}", crate::jobs::table(header, &cells));
    }
    Ok(())
}

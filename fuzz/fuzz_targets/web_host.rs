//! Fuzzes the web listener's `Host` check: any header value gives a name or
//! a refusal, never a panic; a name is lower-case, non-empty and reads
//! back as itself; a loopback name is allowed without configuration and
//! nothing else is; a well-formed value listed in `[web] hosts` is allowed.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::daemon::web::host::{allowed, host_name, LOOPBACK_HOSTS};

fuzz_target!(|data: &[u8]| {
    let Ok(value) = std::str::from_utf8(data) else {
        return;
    };
    let name = host_name(value);
    if let Some(n) = &name {
        assert!(!n.is_empty());
        assert_eq!(n, &n.to_ascii_lowercase());
        assert_eq!(host_name(n).as_deref(), Some(n.as_str()), "{value:?}");
    }
    let bare = allowed(Some(value), &[]);
    assert_eq!(
        bare,
        name.as_deref().is_some_and(|n| LOOPBACK_HOSTS.contains(&n)),
        "{value:?}"
    );
    assert_eq!(allowed(Some(value), &[value.to_owned()]), name.is_some(), "{value:?}");
    assert!(!allowed(None, &[value.to_owned()]));
});

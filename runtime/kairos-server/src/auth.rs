//! Tokens and roles: who may talk to a runtime, and what they may do.

use std::io::{Read as _, Write as _};
use std::path::Path;

use anyhow::{Context as _, bail};
use kairos_protocol::{ErrorCode, MIN_TOKEN_CHARS, PROTOCOL_VERSION, ProtocolError, Role, Token};

/// The tokens a server accepts. With none, every client is let in (loopback only). Its `Debug` shows
/// which tokens there are, never what they are ([`Token`]'s own `Debug`).
#[derive(Debug, Default)]
pub struct Access {
    operator: Option<Token>,
    monitor: Option<Token>,
}

/// Reads the token in `path`, or writes a fresh one there (readable only by its owner) if the file does not
/// exist. Returns the token and whether it was created.
pub fn load_or_create_token(path: &Path) -> anyhow::Result<(Token, bool)> {
    let shown = path.display();
    // `exists` would read "cannot tell" (a folder that may not be searched) as "missing", and a fresh
    // token would be written, or fail to be, in place of one that may well be there.
    let exists = path
        .try_exists()
        .with_context(|| format!("cannot reach the token file {shown}"))?;
    if exists {
        let mut text = String::new();
        std::fs::File::open(path)
            .and_then(|mut f| f.read_to_string(&mut text))
            .with_context(|| format!("cannot read the token file {shown}"))?;
        let token = text.lines().next().unwrap_or("").trim().to_owned();
        let length = token.chars().count();
        if length < MIN_TOKEN_CHARS {
            bail!(
                "the token in {shown} has {length} characters; use at least {MIN_TOKEN_CHARS} \
                 (e.g. `openssl rand -hex 32 > {shown}`, or delete the file to have one made)"
            );
        }
        return Ok((Token::new(token), false));
    }
    let mut random = [0_u8; 32];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut random))
        .context("cannot read random bytes from /dev/urandom for a token")?;
    let token = random.iter().fold(String::with_capacity(64), |mut hex, byte| {
        use std::fmt::Write as _;
        let _ = write!(hex, "{byte:02x}");
        hex
    });
    let mut file = {
        use std::os::unix::fs::OpenOptionsExt as _;
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(path)
            .with_context(|| format!("cannot create the token file {shown}"))?
    };
    writeln!(file, "{token}").with_context(|| format!("cannot write the token file {shown}"))?;
    Ok((Token::new(token), true))
}

impl Access {
    /// Accepts `operator` (both roles) and `monitor` (monitor only) tokens.
    pub fn new(operator: Option<Token>, monitor: Option<Token>) -> Self {
        Access { operator, monitor }
    }

    /// Whether any token is required.
    pub fn requires_token(&self) -> bool {
        self.operator.is_some() || self.monitor.is_some()
    }

    /// The role a `hello` earns: checks the protocol version, then the token against the role wanted.
    pub fn grant(
        &self,
        protocol: u32,
        token: Option<&Token>,
        wanted: Option<Role>,
    ) -> Result<Role, ProtocolError> {
        if protocol != PROTOCOL_VERSION {
            return Err(ProtocolError::new(
                ErrorCode::UnsupportedVersion,
                format!(
                    "this runtime speaks protocol version {PROTOCOL_VERSION} and the client {protocol}; \
                     use a client and a runtime of matching versions"
                ),
            ));
        }
        let asked = wanted;
        if !self.requires_token() {
            return Ok(asked.unwrap_or(Role::Operator));
        }
        let Some(token) = token else {
            return Err(ProtocolError::new(
                ErrorCode::Unauthorized,
                "this runtime requires a token: send it in hello's \"token\" field",
            ));
        };
        // `Token`'s equality is `tokens_match`: constant time.
        let is_operator = self.operator.as_ref() == Some(token);
        let is_monitor = self.monitor.as_ref() == Some(token);
        match (is_operator, is_monitor, asked) {
            (true, _, role) => Ok(role.unwrap_or(Role::Operator)),
            // A monitor token grants monitor, whether or not the client said so.
            (false, true, None | Some(Role::Monitor)) => Ok(Role::Monitor),
            (false, true, Some(Role::Operator)) => Err(ProtocolError::new(
                ErrorCode::Forbidden,
                "this token grants the monitor role only: ask for \"role\": \"monitor\", or leave role out",
            )),
            (false, false, _) => Err(ProtocolError::new(ErrorCode::Unauthorized, "wrong token")),
        }
    }
}

#[cfg(test)]
mod tests {
    use kairos_protocol::{ErrorCode, Role, Token};

    use super::{Access, load_or_create_token};

    #[test]
    fn tokens_grant_their_roles_and_nothing_more() {
        let operator = Token::new("o".repeat(40));
        let monitor = Token::new("m".repeat(40));
        let access = Access::new(Some(operator.clone()), Some(monitor.clone()));
        assert_eq!(
            format!("{access:?}"),
            "Access { operator: Some(Token(***)), monitor: Some(Token(***)) }"
        );
        assert_eq!(access.grant(1, Some(&operator), None), Ok(Role::Operator));
        assert_eq!(
            access.grant(1, Some(&operator), Some(Role::Monitor)),
            Ok(Role::Monitor)
        );
        assert_eq!(
            access.grant(1, Some(&monitor), Some(Role::Monitor)),
            Ok(Role::Monitor)
        );
        let code = |r: Result<Role, kairos_protocol::ProtocolError>| r.unwrap_err().code;
        assert_eq!(access.grant(1, Some(&monitor), None), Ok(Role::Monitor));
        assert_eq!(
            code(access.grant(1, Some(&monitor), Some(Role::Operator))),
            ErrorCode::Forbidden
        );
        assert_eq!(
            code(access.grant(1, Some(&Token::new("nope")), None)),
            ErrorCode::Unauthorized
        );
        assert_eq!(code(access.grant(1, None, None)), ErrorCode::Unauthorized);
        assert_eq!(
            code(access.grant(2, Some(&operator), None)),
            ErrorCode::UnsupportedVersion
        );
        assert_eq!(Access::default().grant(1, None, None), Ok(Role::Operator));
    }

    #[test]
    fn a_missing_token_file_gets_a_fresh_private_token_and_a_short_one_is_refused() {
        use std::os::unix::fs::PermissionsExt as _;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("token");
        let (token, created) = load_or_create_token(&path).unwrap();
        assert!(created && token.reveal().len() == 64);
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);
        assert_eq!(load_or_create_token(&path).unwrap(), (token, false));
        std::fs::write(&path, "short\n").unwrap();
        let error = load_or_create_token(&path).unwrap_err().to_string();
        assert!(
            error.contains("at least 32") && error.contains("openssl rand -hex 32"),
            "{error}"
        );
    }
}

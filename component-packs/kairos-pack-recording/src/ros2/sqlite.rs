//! `SQLite`, read-only, for rosbag2's older storage (`.db3`): the system's `libsqlite3`, loaded at run time
//! where it is installed (every Linux distribution ships it: Python needs it), called through the ten
//! functions reading rows takes.
//!
//! Decision: loaded with `dlopen`, not linked or bundled, as the vision pack loads libjpeg-turbo: the first
//! build of Kairos compiles no C library, and a machine without `SQLite` still replays MCAP bags; a `.db3`
//! there is refused with the reason.
#![allow(
    unsafe_code,
    reason = "calling a C library loaded at run time; each call says why it is sound"
)]

use std::ffi::{CStr, CString, c_char, c_int, c_uchar, c_void};
use std::path::Path;
use std::sync::OnceLock;

type Connection = *mut c_void;
type Statement = *mut c_void;

/// The functions used, from the library found.
struct Api {
    open_v2: unsafe extern "C" fn(*const c_char, *mut Connection, c_int, *const c_char) -> c_int,
    close: unsafe extern "C" fn(Connection) -> c_int,
    errmsg: unsafe extern "C" fn(Connection) -> *const c_char,
    prepare_v2:
        unsafe extern "C" fn(Connection, *const c_char, c_int, *mut Statement, *mut *const c_char) -> c_int,
    step: unsafe extern "C" fn(Statement) -> c_int,
    finalize: unsafe extern "C" fn(Statement) -> c_int,
    column_int64: unsafe extern "C" fn(Statement, c_int) -> i64,
    column_text: unsafe extern "C" fn(Statement, c_int) -> *const c_uchar,
    column_blob: unsafe extern "C" fn(Statement, c_int) -> *const c_void,
    column_bytes: unsafe extern "C" fn(Statement, c_int) -> c_int,
    /// Kept loaded for as long as the process runs: the functions above point into it.
    _library: libloading::Library,
}

/// sqlite3.h's result codes and flags used here.
const SQLITE_OK: c_int = 0;
const SQLITE_ROW: c_int = 100;
const SQLITE_DONE: c_int = 101;
const SQLITE_OPEN_READONLY: c_int = 1;

/// The library's file names, the versioned one first (the unversioned link comes with the -dev package).
const NAMES: [&str; 2] = ["libsqlite3.so.0", "libsqlite3.so"];

/// Why a `.db3` file cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SqliteError {
    /// The system has no `libsqlite3`.
    #[error("reading a .db3 bag needs SQLite (libsqlite3.so.0), which is not installed")]
    NotInstalled,
    /// `SQLite` takes NUL-terminated paths.
    #[error("a path with a NUL byte")]
    NulInPath,
    /// The file is not a database `SQLite` opens.
    #[error("not a SQLite database: {0}")]
    NotADatabase(String),
    /// `SQLite` takes NUL-terminated queries.
    #[error("a query with a NUL byte")]
    NulInQuery,
    /// A query refused or failed part way, with `SQLite`'s message.
    #[error("{sql}: {message}")]
    Query {
        /// The query.
        sql: String,
        /// What `SQLite` said.
        message: String,
    },
}

fn api() -> Result<&'static Api, SqliteError> {
    static API: OnceLock<Option<Api>> = OnceLock::new();
    API.get_or_init(|| NAMES.iter().find_map(|name| load(name)))
        .as_ref()
        .ok_or(SqliteError::NotInstalled)
}

fn load(name: &str) -> Option<Api> {
    // SAFETY: loading libsqlite3 runs no initialisation code with preconditions of its own.
    let library = unsafe { libloading::Library::new(name) }.ok()?;
    // SAFETY: each symbol is declared with the signature sqlite3.h gives it (stable since `SQLite` 3.5), and
    // the pointers are used only while `library`, stored beside them, stays loaded.
    unsafe {
        Some(Api {
            open_v2: *library.get(b"sqlite3_open_v2\0").ok()?,
            close: *library.get(b"sqlite3_close\0").ok()?,
            errmsg: *library.get(b"sqlite3_errmsg\0").ok()?,
            prepare_v2: *library.get(b"sqlite3_prepare_v2\0").ok()?,
            step: *library.get(b"sqlite3_step\0").ok()?,
            finalize: *library.get(b"sqlite3_finalize\0").ok()?,
            column_int64: *library.get(b"sqlite3_column_int64\0").ok()?,
            column_text: *library.get(b"sqlite3_column_text\0").ok()?,
            column_blob: *library.get(b"sqlite3_column_blob\0").ok()?,
            column_bytes: *library.get(b"sqlite3_column_bytes\0").ok()?,
            _library: library,
        })
    }
}

/// A database opened read-only.
pub struct Database {
    api: &'static Api,
    connection: Connection,
}

/// One row of a query's result, valid while the callback given it runs.
pub struct Row<'a> {
    api: &'static Api,
    statement: Statement,
    _query: std::marker::PhantomData<&'a ()>,
}

impl Row<'_> {
    /// Column `index` as an integer.
    pub fn integer(&self, index: c_int) -> i64 {
        // SAFETY: the statement is stepped to a row and not finalised while the row lives.
        unsafe { (self.api.column_int64)(self.statement, index) }
    }

    /// Column `index` as text (empty when NULL).
    pub fn text(&self, index: c_int) -> String {
        String::from_utf8_lossy(self.bytes(index, true)).into_owned()
    }

    /// Column `index` as bytes (empty when NULL).
    pub fn blob(&self, index: c_int) -> &[u8] {
        self.bytes(index, false)
    }

    fn bytes(&self, index: c_int, text: bool) -> &[u8] {
        // SAFETY: the statement is stepped to a row; as sqlite3.h requires, the pointer is taken before
        // the length, and both stay valid until the next step, after this row's callback returns.
        unsafe {
            let pointer = if text {
                (self.api.column_text)(self.statement, index).cast::<u8>()
            } else {
                (self.api.column_blob)(self.statement, index).cast::<u8>()
            };
            let length = usize::try_from((self.api.column_bytes)(self.statement, index)).unwrap_or(0);
            if pointer.is_null() || length == 0 {
                &[]
            } else {
                std::slice::from_raw_parts(pointer, length)
            }
        }
    }
}

impl Database {
    /// Opens `path` read-only.
    pub fn open(path: &Path) -> Result<Database, SqliteError> {
        let api = api()?;
        let name = CString::new(path.as_os_str().as_encoded_bytes()).map_err(|_| SqliteError::NulInPath)?;
        let mut connection: Connection = std::ptr::null_mut();
        // SAFETY: `name` is a NUL-terminated string alive for the call; `SQLite` writes the connection
        // (even on failure, to be closed) into `connection`.
        let result = unsafe {
            (api.open_v2)(
                name.as_ptr(),
                &raw mut connection,
                SQLITE_OPEN_READONLY,
                std::ptr::null(),
            )
        };
        let database = Database { api, connection };
        if result != SQLITE_OK {
            return Err(SqliteError::NotADatabase(database.error()));
        }
        Ok(database)
    }

    fn error(&self) -> String {
        if self.connection.is_null() {
            return "out of memory".to_owned();
        }
        // SAFETY: the connection is open; the message is a NUL-terminated string `SQLite` owns, copied at once.
        unsafe { CStr::from_ptr((self.api.errmsg)(self.connection)) }
            .to_string_lossy()
            .into_owned()
    }

    /// Runs `sql`, calling `each` with every row until it says to break.
    pub fn query(
        &self,
        sql: &str,
        mut each: impl FnMut(&Row<'_>) -> std::ops::ControlFlow<()>,
    ) -> Result<(), SqliteError> {
        let failed = |message: String| SqliteError::Query {
            sql: sql.to_owned(),
            message,
        };
        let text = CString::new(sql).map_err(|_| SqliteError::NulInQuery)?;
        let mut statement: Statement = std::ptr::null_mut();
        // SAFETY: the connection is open and `text` NUL-terminated (-1: read to the NUL).
        let prepared = unsafe {
            (self.api.prepare_v2)(
                self.connection,
                text.as_ptr(),
                -1,
                &raw mut statement,
                std::ptr::null_mut(),
            )
        };
        if prepared != SQLITE_OK {
            return Err(failed(self.error()));
        }
        let mut outcome = Ok(());
        loop {
            // SAFETY: the statement is prepared and not finalised.
            match unsafe { (self.api.step)(statement) } {
                SQLITE_ROW => {
                    let row = Row {
                        api: self.api,
                        statement,
                        _query: std::marker::PhantomData,
                    };
                    if each(&row).is_break() {
                        break;
                    }
                }
                SQLITE_DONE => break,
                _ => {
                    outcome = Err(failed(self.error()));
                    break;
                }
            }
        }
        // SAFETY: prepared above, finalised once.
        unsafe { (self.api.finalize)(statement) };
        outcome
    }
}

impl Drop for Database {
    fn drop(&mut self) {
        // SAFETY: the connection (possibly a failed open's, which must be closed too) is closed once; every
        // statement was finalised by `query`.
        unsafe { (self.api.close)(self.connection) };
    }
}

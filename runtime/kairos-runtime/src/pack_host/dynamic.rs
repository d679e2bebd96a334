//! A component living in a loaded pack library, driven through its component table.

#![allow(
    unsafe_code,
    reason = "calls through a pack's component table with raw instance and frame pointers"
)]

use std::ffi::c_void;

use kairos_sdk_core::abi::{KComponentVTable, KError, KLifecycleFn, KNamedFn, KStr};
use kairos_sdk_core::host::status_error;
use kairos_sdk_core::{Component, ComponentError, ComponentResult, Context, Value};

use super::functions::{HOST_API, HostFrame};

const ERROR_CAPACITY: usize = 1024;

/// A component table whose every function is there: what the loader makes of a pack's table, which it
/// refuses when one is null.
#[derive(Debug, Clone, Copy)]
pub(super) struct CheckedVTable {
    data: *const c_void,
    create: unsafe extern "C" fn(data: *const c_void) -> *mut c_void,
    destroy: unsafe extern "C" fn(instance: *mut c_void),
    birth: KLifecycleFn,
    core: KLifecycleFn,
    death: KLifecycleFn,
    property_changed: KNamedFn,
    action: KNamedFn,
}

// SAFETY: the table is immutable data in a library that is never unloaded; the ABI requires its functions
// to be callable from any thread.
unsafe impl Send for CheckedVTable {}
// SAFETY: as above.
unsafe impl Sync for CheckedVTable {}

impl CheckedVTable {
    /// The table's functions, or the C name of the first one that is null.
    pub(super) fn of(table: &KComponentVTable) -> Result<Self, &'static str> {
        Ok(CheckedVTable {
            data: table.data,
            create: table.create.ok_or("create")?,
            destroy: table.destroy.ok_or("destroy")?,
            birth: table.birth.ok_or("birth")?,
            core: table.core.ok_or("core")?,
            death: table.death.ok_or("death")?,
            property_changed: table.property_changed.ok_or("property_changed")?,
            action: table.action.ok_or("action")?,
        })
    }
}

/// A component living in a loaded pack library, driven through its vtable.
pub struct DynamicComponent {
    vtable: CheckedVTable,
    instance: *mut c_void,
    frame: HostFrame,
    error: Vec<u8>,
}

// SAFETY: a component instance is used by one thread at a time (the engine moves it into its thread or
// behind a mutex); the ABI requires packs to allow an instance to move between threads.
unsafe impl Send for DynamicComponent {}

impl std::fmt::Debug for DynamicComponent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DynamicComponent")
            .field("instance", &self.instance)
            .finish_non_exhaustive()
    }
}

impl DynamicComponent {
    pub(super) fn new(vtable: CheckedVTable) -> Self {
        // SAFETY: the vtable passed the loader's checks; `create` may return null (its constructor failed),
        // which `call` reports as the component's failure.
        let instance = unsafe { (vtable.create)(vtable.data) };
        DynamicComponent {
            vtable,
            instance,
            frame: HostFrame::new(),
            error: vec![0; ERROR_CAPACITY],
        }
    }

    fn call(
        &mut self,
        stage: &str,
        ctx: &mut Context,
        invoke: impl FnOnce(*mut c_void, *mut c_void, *mut KError) -> i32,
    ) -> ComponentResult {
        if self.instance.is_null() {
            return Err(ComponentError::failed(format_args!(
                "its constructor failed in the pack (during {stage})"
            )));
        }
        self.frame.ctx = std::ptr::from_mut(ctx);
        let mut error = KError {
            buffer: self.error.as_mut_ptr(),
            capacity: self.error.len(),
            len: 0,
        };
        let code = invoke(
            self.instance,
            std::ptr::from_mut(&mut self.frame).cast(),
            &raw mut error,
        );
        self.frame.ctx = std::ptr::null_mut();
        let message = || {
            let bytes = self.error.get(..error.len.min(ERROR_CAPACITY)).unwrap_or(&[]);
            let text = String::from_utf8_lossy(bytes).into_owned();
            if text.is_empty() {
                format!("{stage} failed in the pack")
            } else {
                text
            }
        };
        status_error(code, message)
    }
}

impl Component for DynamicComponent {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.birth;
        // SAFETY: instance, frame and error are valid for the call, as the ABI requires.
        self.call("birth", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, e)
        })
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.core;
        // SAFETY: as in `birth`.
        self.call("core", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, e)
        })
    }

    fn death(&mut self, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.death;
        // SAFETY: as in `birth`.
        self.call("death", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, e)
        })
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.property_changed;
        let name = KStr::new(name);
        // SAFETY: as in `birth`; `name` lives for the call.
        self.call("property_changed", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, name, e)
        })
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.action;
        let name = KStr::new(name);
        // SAFETY: as in `birth`; `name` lives for the call.
        self.call("action", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, name, e)
        })
    }
}

impl Drop for DynamicComponent {
    fn drop(&mut self) {
        if !self.instance.is_null() {
            // SAFETY: `instance` came from this vtable's `create` and is destroyed once.
            unsafe { (self.vtable.destroy)(self.instance) };
        }
    }
}

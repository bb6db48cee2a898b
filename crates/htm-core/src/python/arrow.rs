//! Tables leave the core as Arrow record batches: the Arrow C Data Interface, exported through
//! the PyCapsule protocol (`__arrow_c_array__`), so `pyarrow.record_batch(table)` (or any Arrow
//! consumer) takes the core's own column buffers without a copy and without a Python loop.
//!
//! Written by hand (about a hundred lines) instead of taking the `arrow` crates: the tables are
//! flat structs of primitive columns, and `arrow-array`/`pyo3-arrow` would add several crates to
//! every build of the extension for what these few structs express
//! (<https://arrow.apache.org/docs/format/CDataInterface.html>).
use std::ffi::{c_char, c_void, CStr, CString};
use std::ptr;
use std::sync::Arc;

use pyo3::prelude::*;
use pyo3::types::PyCapsule;

/// One column: its name and a borrowed view of its values (kept alive by the table's owner).
pub(crate) enum Column<'a> {
    U8(&'a [u8]),
    U32(&'a [u32]),
    U64(&'a [u64]),
    F64(&'a [f64]),
}

impl Column<'_> {
    fn format(&self) -> &'static CStr {
        match self {
            Column::U8(_) => c"C",
            Column::U32(_) => c"I",
            Column::U64(_) => c"L",
            Column::F64(_) => c"g",
        }
    }
    fn len(&self) -> usize {
        match self {
            Column::U8(v) => v.len(),
            Column::U32(v) => v.len(),
            Column::U64(v) => v.len(),
            Column::F64(v) => v.len(),
        }
    }
    fn ptr(&self) -> *const c_void {
        match self {
            Column::U8(v) => v.as_ptr().cast(),
            Column::U32(v) => v.as_ptr().cast(),
            Column::U64(v) => v.as_ptr().cast(),
            Column::F64(v) => v.as_ptr().cast(),
        }
    }
}

/// A table the bindings can export: named, typed columns of equal length over data it owns.
pub(crate) trait Columns: Send + Sync + 'static {
    fn columns(&self) -> Vec<(&'static str, Column<'_>)>;
}

#[repr(C)]
pub(crate) struct ArrowSchema {
    format: *const c_char,
    name: *const c_char,
    metadata: *const c_char,
    flags: i64,
    n_children: i64,
    children: *mut *mut ArrowSchema,
    dictionary: *mut ArrowSchema,
    release: Option<unsafe extern "C" fn(*mut ArrowSchema)>,
    private_data: *mut c_void,
}

#[repr(C)]
pub(crate) struct ArrowArray {
    length: i64,
    null_count: i64,
    offset: i64,
    n_buffers: i64,
    n_children: i64,
    buffers: *mut *const c_void,
    children: *mut *mut ArrowArray,
    dictionary: *mut ArrowArray,
    release: Option<unsafe extern "C" fn(*mut ArrowArray)>,
    private_data: *mut c_void,
}

// SAFETY: the structs own (through `private_data`) everything they point to; the consumer
// releases them once, from any thread (the C Data Interface's contract).
unsafe impl Send for ArrowSchema {}
unsafe impl Send for ArrowArray {}

impl Drop for ArrowSchema {
    fn drop(&mut self) {
        if let Some(r) = self.release {
            unsafe { r(self) }
        }
    }
}

impl Drop for ArrowArray {
    fn drop(&mut self) {
        if let Some(r) = self.release {
            unsafe { r(self) }
        }
    }
}

struct SchemaData {
    _format: &'static CStr,
    _name: CString,
    children: Vec<*mut ArrowSchema>,
}

unsafe extern "C" fn release_schema(s: *mut ArrowSchema) {
    let s = unsafe { &mut *s };
    let data = unsafe { Box::from_raw(s.private_data as *mut SchemaData) };
    for c in data.children {
        drop(unsafe { Box::from_raw(c) }); // its Drop releases it
    }
    s.release = None;
}

fn schema(format: &'static CStr, name: &str, nullable: bool, children: Vec<ArrowSchema>) -> ArrowSchema {
    let name = CString::new(name).expect("column names have no NUL");
    let mut children: Vec<*mut ArrowSchema> = children.into_iter().map(|c| Box::into_raw(Box::new(c))).collect();
    let data = Box::new(SchemaData { _format: format, _name: name, children: Vec::new() });
    let (n, cptr) = (children.len() as i64, children.as_mut_ptr());
    let mut s = ArrowSchema {
        format: format.as_ptr(),
        name: data._name.as_ptr(),
        metadata: ptr::null(),
        flags: if nullable { 2 } else { 0 }, // ARROW_FLAG_NULLABLE
        n_children: n,
        children: if n > 0 { cptr } else { ptr::null_mut() },
        dictionary: ptr::null_mut(),
        release: Some(release_schema),
        private_data: ptr::null_mut(),
    };
    let mut data = data;
    data.children = children; // moving the Vec keeps its heap buffer (and `cptr`) in place
    s.private_data = Box::into_raw(data).cast();
    s
}

struct ArrayData {
    _owner: Arc<dyn Columns>,
    buffers: Vec<*const c_void>,
    children: Vec<*mut ArrowArray>,
}

unsafe extern "C" fn release_array(a: *mut ArrowArray) {
    let a = unsafe { &mut *a };
    let data = unsafe { Box::from_raw(a.private_data as *mut ArrayData) };
    for c in data.children {
        drop(unsafe { Box::from_raw(c) });
    }
    a.release = None;
}

fn array(owner: &Arc<dyn Columns>, len: usize, buffers: Vec<*const c_void>, children: Vec<ArrowArray>) -> ArrowArray {
    let mut data = Box::new(ArrayData {
        _owner: owner.clone(),
        buffers,
        children: children.into_iter().map(|c| Box::into_raw(Box::new(c))).collect(),
    });
    let n = data.children.len() as i64;
    ArrowArray {
        length: len as i64,
        null_count: 0,
        offset: 0,
        n_buffers: data.buffers.len() as i64,
        n_children: n,
        buffers: data.buffers.as_mut_ptr(),
        children: if n > 0 { data.children.as_mut_ptr() } else { ptr::null_mut() },
        dictionary: ptr::null_mut(),
        release: Some(release_array),
        private_data: Box::into_raw(data).cast(),
    }
}

/// The schema of `t`: a struct of its columns, as an Arrow record batch is. The columns are
/// declared nullable (none holds a null: `null_count` 0), as pyarrow declares a numpy column, so
/// a table written from the batch has the same Parquet schema as one written from numpy.
fn struct_schema(t: &dyn Columns) -> ArrowSchema {
    let children = t.columns().iter().map(|(name, c)| schema(c.format(), name, true, Vec::new())).collect();
    schema(c"+s", "", false, children)
}

/// `(schema capsule, array capsule)` of `owner` as a struct array (PyCapsule interface).
pub(crate) fn export<'py>(py: Python<'py>, owner: Arc<dyn Columns>) -> PyResult<(Bound<'py, PyCapsule>, Bound<'py, PyCapsule>)> {
    let cols = owner.columns();
    let len = cols.first().map_or(0, |(_, c)| c.len());
    if let Some((name, _)) = cols.iter().find(|(_, c)| c.len() != len) {
        return Err(super::InputError::new_err(format!("table column `{name}` has a different length")));
    }
    let children = cols.iter().map(|(_, c)| array(&owner, len, vec![ptr::null(), c.ptr()], Vec::new())).collect();
    let arr = array(&owner, len, vec![ptr::null()], children);
    let sch = struct_schema(&*owner);
    drop(cols);
    Ok((PyCapsule::new_with_value(py, sch, c"arrow_schema")?, PyCapsule::new_with_value(py, arr, c"arrow_array")?))
}

/// The schema capsule alone (`__arrow_c_schema__`).
pub(crate) fn export_schema<'py>(py: Python<'py>, t: &dyn Columns) -> PyResult<Bound<'py, PyCapsule>> {
    PyCapsule::new_with_value(py, struct_schema(t), c"arrow_schema")
}

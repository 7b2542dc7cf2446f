//! LibTorch code that tch does not expose, in models/cpp/torch_kernels.cpp (compiled by
//! models/build.rs against the libtorch torch-sys found; the `libtorch` feature only).
//!
//! - [`autograd_grad`]: LibTorch's autograd engine started from an output with a given
//!   gradient (tch starts it only from a scalar with a gradient of one), for
//!   [`crate::layers`].
//! - [`segmentation_loss`]: the segmenter's merged cross-entropy plus Dice loss and its
//!   gradient in two passes over the logits, for [`crate::segmenter::loss`].
#![allow(unsafe_code)]

use std::ffi::{CStr, c_char, c_int};

use torch_sys::C_tensor;

unsafe extern "C" {
    fn pipeline_autograd_grad(
        output: *const C_tensor,
        grad: *const C_tensor,
        inputs: *const *const C_tensor,
        n: c_int,
        results: *mut *mut C_tensor,
        error: *mut c_char,
        error_len: usize,
    ) -> c_int;

    fn pipeline_segmentation_loss(
        logits: *const C_tensor,
        allowed: *const C_tensor,
        weights: *const C_tensor,
        single: *const C_tensor,
        present: *const C_tensor,
        weight_sum: f64,
        dice_weight: f64,
        loss: *mut *mut C_tensor,
        grad: *mut *mut C_tensor,
        error: *mut c_char,
        error_len: usize,
    ) -> c_int;
}

/// Calls a function of torch_kernels.cpp with an error buffer; `Err` carries its message.
fn checked(call: impl FnOnce(*mut c_char, usize) -> c_int) -> Result<(), String> {
    let mut error = [0 as c_char; 512];
    if call(error.as_mut_ptr(), error.len()) == 0 {
        return Ok(());
    }
    // SAFETY: on failure the C++ side wrote a zero-terminated message into the buffer.
    Err(unsafe { CStr::from_ptr(error.as_ptr()) }
        .to_string_lossy()
        .into_owned())
}

/// Takes ownership of a tensor the C++ side created with `new` (tch's `at_free` deletes it).
///
/// SAFETY: `pointer` comes from a successful call of torch_kernels.cpp, once.
unsafe fn owned(pointer: *mut C_tensor) -> tch::Tensor {
    // SAFETY: see the function's contract.
    unsafe { tch::Tensor::from_ptr(pointer) }
}

/// The gradients of `output` with respect to `inputs` (leaves of its graph) for the output
/// gradient `grad` (of `output`'s shape and kind); frees the graph.
pub fn autograd_grad(
    output: &tch::Tensor,
    grad: &tch::Tensor,
    inputs: &[&tch::Tensor],
) -> Result<Vec<tch::Tensor>, String> {
    let pointers: Vec<*const C_tensor> = inputs.iter().map(|t| t.as_ptr()).collect();
    let mut results = vec![std::ptr::null_mut(); inputs.len()];
    let n = c_int::try_from(inputs.len()).map_err(|_| "too many inputs".to_string())?;
    checked(|error, len| {
        // SAFETY: the pointers come from tensors borrowed for the call, and `results` has
        // room for one tensor per input.
        unsafe {
            pipeline_autograd_grad(
                output.as_ptr(),
                grad.as_ptr(),
                pointers.as_ptr(),
                n,
                results.as_mut_ptr(),
                error,
                len,
            )
        }
    })?;
    // SAFETY: the call succeeded and wrote one new tensor per input.
    Ok(results.into_iter().map(|p| unsafe { owned(p) }).collect())
}

/// The tensors of a `LossTargets` (shapes in [`segmentation_loss`]).
#[derive(Debug, Clone, Copy)]
pub struct LossInputs<'a> {
    pub allowed: &'a tch::Tensor,
    pub weights: &'a tch::Tensor,
    pub single: &'a tch::Tensor,
    pub present: &'a tch::Tensor,
    pub weight_sum: f64,
}

/// `CE + dice_weight · Dice` of `logits [B, C, H, W]` (models::segmenter::loss) and its
/// gradient with respect to the logits: `(loss [1], gradient [B, C, H, W])`. The targets are
/// `allowed [B, C, H, W]`, `weights [B, H, W]`, `single [B, 1, H, W]` and `present [C]`.
/// The result does not depend on the number of threads.
pub fn segmentation_loss(
    logits: &tch::Tensor,
    targets: LossInputs<'_>,
    dice_weight: f64,
) -> Result<(tch::Tensor, tch::Tensor), String> {
    let (mut loss, mut grad) = (std::ptr::null_mut(), std::ptr::null_mut());
    checked(|error, len| {
        // SAFETY: the pointers come from tensors borrowed for the call.
        unsafe {
            pipeline_segmentation_loss(
                logits.as_ptr(),
                targets.allowed.as_ptr(),
                targets.weights.as_ptr(),
                targets.single.as_ptr(),
                targets.present.as_ptr(),
                targets.weight_sum,
                dice_weight,
                &mut loss,
                &mut grad,
                error,
                len,
            )
        }
    })?;
    // SAFETY: the call succeeded and wrote both.
    Ok(unsafe { (owned(loss), owned(grad)) })
}

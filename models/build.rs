//! With the `libtorch` feature, compiles `cpp/torch_kernels.cpp` against the libtorch that
//! torch-sys found (its include folder sits beside the `lib` folder torch-sys reports).

fn main() {
    println!("cargo:rerun-if-changed=cpp/torch_kernels.cpp");
    #[cfg(feature = "libtorch")]
    compile_torch_kernels();
}

#[cfg(feature = "libtorch")]
fn compile_torch_kernels() {
    let lib = std::env::var("DEP_TCH_LIBTORCH_LIB")
        .expect("torch-sys reports its libtorch folder as DEP_TCH_LIBTORCH_LIB");
    let root = std::path::Path::new(&lib)
        .parent()
        .expect("libtorch's lib folder has a parent")
        .to_path_buf();
    // torch-sys's own flags, so both objects agree on the C++ ABI.
    let cxx11_abi = std::env::var("LIBTORCH_CXX11_ABI").unwrap_or_else(|_| "1".to_string());
    println!("cargo:rerun-if-env-changed=LIBTORCH_CXX11_ABI");
    cc::Build::new()
        .cpp(true)
        .pic(true)
        .warnings(false)
        // Optimised in test builds too, with the loops over a block's pixels vectorised: the
        // loss kernel runs over every pixel of every training step.
        .opt_level(3)
        // Lets the per-class sums over a block vectorise (reassociated, deterministically), and
        // `log` skip errno; NaN and infinity keep their meaning (no -ffinite-math-only).
        .flag("-fassociative-math")
        .flag("-fno-signed-zeros")
        .flag("-fno-trapping-math")
        .flag("-fno-math-errno")
        .include(root.join("include"))
        .include(root.join("include/torch/csrc/api/include"))
        .flag("-std=c++17")
        .flag(format!("-D_GLIBCXX_USE_CXX11_ABI={cxx11_abi}"))
        .flag("-DGLOG_USE_GLOG_EXPORT")
        .file("cpp/torch_kernels.cpp")
        .compile("pipeline_torch_kernels");
}

//! Feature spaces WD compares images in: each turns an sRGB image into a list of C × H × W
//! arrays and can carry the gradient back from those arrays to the image.
//!
//! * [`pyramid::Pyramid`] (`pyramid`, `pyramid-colour`): weight-free oriented filter banks.
//! * [`vgg16::Vgg16`] (`vgg16=PATH`): the paper's VGG-16 features from a safetensors file.

pub mod pyramid;
pub mod vgg16;

use std::path::PathBuf;
use std::str::FromStr;

use super::tensor::{Real, Tensor};

/// ImageNet channel means (RGB) used to normalise images before feature extraction.
pub const IMAGENET_MEAN: [f64; 3] = [0.485, 0.456, 0.406];
/// ImageNet channel standard deviations (RGB).
pub const IMAGENET_STD: [f64; 3] = [0.229, 0.224, 0.225];

/// Carries gradients w.r.t. the feature arrays back to the input image.
pub trait Backward<T>: Send {
    /// `grads[i]` has the shape of feature array `i`; returns the gradient w.r.t. the
    /// 3 × H × W image given to [`FeatureSpace::extract`].
    fn backward(self: Box<Self>, grads: &[Tensor<T>]) -> Tensor<T>;
}

/// Feature arrays of one image and what is needed to differentiate them.
pub struct Extracted<T> {
    pub arrays: Vec<Tensor<T>>,
    pub tape: Box<dyn Backward<T>>,
}

/// A fixed (not trained) map from an image to feature arrays.
pub trait FeatureSpace<T: Real>: Send + Sync {
    /// Short name for reports (`pyramid`, `vgg16`).
    fn name(&self) -> &'static str;

    /// Feature arrays of a 3 × H × W sRGB image with values in [0, 1], with a backward tape.
    fn extract(&self, image: &Tensor<T>) -> Extracted<T>;

    /// Feature arrays only (the reference side).
    fn features(&self, image: &Tensor<T>) -> Vec<Tensor<T>> {
        self.extract(image).arrays
    }
}

/// `(x − mean) / std` per channel with the ImageNet constants.
pub fn normalize<T: Real>(image: &Tensor<T>) -> Tensor<T> {
    assert_eq!(image.c, 3, "feature spaces take RGB images");
    let n = image.plane_len();
    let mut out = image.clone();
    for c in 0..3 {
        let (m, s) = (T::c(IMAGENET_MEAN[c]), T::c(IMAGENET_STD[c]));
        out.data[c * n..(c + 1) * n].iter_mut().for_each(|v| *v = (*v - m) / s);
    }
    out
}

/// Adjoint of [`normalize`] (gradient w.r.t. the unnormalised image).
pub fn normalize_adjoint<T: Real>(grad: &mut Tensor<T>) {
    let n = grad.plane_len();
    for c in 0..3 {
        let s = T::c(IMAGENET_STD[c]);
        grad.data[c * n..(c + 1) * n].iter_mut().for_each(|v| *v = *v / s);
    }
}

/// Which feature space to use, as given on the command line (`pyramid`, `pyramid-colour` or
/// `vgg16=PATH`).
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum FeatureSpec {
    Pyramid,
    /// The default since session 44 (docs/wd.md §35).
    #[default]
    PyramidColour,
    Vgg16(PathBuf),
}

impl FromStr for FeatureSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once('=') {
            None if s == "pyramid" => Ok(FeatureSpec::Pyramid),
            None if s == "pyramid-colour" => Ok(FeatureSpec::PyramidColour),
            Some(("vgg16", path)) if !path.is_empty() => Ok(FeatureSpec::Vgg16(PathBuf::from(path))),
            _ => Err(format!("unknown feature space `{s}` (expected `pyramid`, `pyramid-colour` or `vgg16=PATH`)")),
        }
    }
}

impl std::fmt::Display for FeatureSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FeatureSpec::Pyramid => write!(f, "pyramid"),
            FeatureSpec::PyramidColour => write!(f, "pyramid-colour"),
            FeatureSpec::Vgg16(p) => write!(f, "vgg16={}", p.display()),
        }
    }
}

impl FeatureSpec {
    /// Whether this is the `pyramid-colour` bank.
    pub fn colour(&self) -> bool {
        *self == FeatureSpec::PyramidColour
    }

    /// Builds the feature space (loads VGG weights when asked).
    ///
    /// # Errors
    /// [`crate::Error::input`] naming the weights file when it cannot be read or is not a VGG-16.
    pub fn build(&self) -> crate::Result<Box<dyn FeatureSpace<f32>>> {
        Ok(match self {
            FeatureSpec::Pyramid => Box::new(pyramid::Pyramid::LUMA),
            FeatureSpec::PyramidColour => Box::new(pyramid::Pyramid::COLOUR),
            FeatureSpec::Vgg16(path) => Box::new(vgg16::Vgg16::<f32>::load(path)?),
        })
    }
}

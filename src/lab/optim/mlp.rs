//! A multilayer perceptron in candle, with ReLU between layers: SAC's actor and critics and
//! the skill policy's network.

use crate::util::SplitMix64;
use candle_core::{Device, Result, Tensor, Var};

/// A multilayer perceptron with ReLU between layers.
pub struct Mlp {
    /// (weight `[out, in]`, bias `[out]`) per layer.
    pub layers: Vec<(Var, Var)>,
}

impl Mlp {
    /// PyTorch's default initialisation: weights and biases uniform in `±1/√fan_in`.
    pub fn new(sizes: &[usize], rng: &mut SplitMix64, dev: &Device) -> Result<Mlp> {
        let mut layers = Vec::new();
        for w in sizes.windows(2) {
            let (i, o) = (w[0], w[1]);
            let bound = 1.0 / (i as f64).sqrt();
            let wv: Vec<f64> = (0..i * o).map(|_| rng.uniform_in(-bound, bound)).collect();
            let bv: Vec<f64> = (0..o).map(|_| rng.uniform_in(-bound, bound)).collect();
            layers.push((
                Var::from_tensor(&Tensor::from_vec(wv, (o, i), dev)?)?,
                Var::from_tensor(&Tensor::from_vec(bv, o, dev)?)?,
            ));
        }
        Ok(Mlp { layers })
    }

    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut x = x.clone();
        let n = self.layers.len();
        for (k, (w, b)) in self.layers.iter().enumerate() {
            x = x
                .matmul(&w.as_tensor().t()?)?
                .broadcast_add(b.as_tensor())?;
            if k + 1 < n {
                x = x.relu()?;
            }
        }
        Ok(x)
    }

    pub fn vars(&self) -> Vec<Var> {
        self.layers
            .iter()
            .flat_map(|(w, b)| [w.clone(), b.clone()])
            .collect()
    }
}

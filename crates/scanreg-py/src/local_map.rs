//! Binding of `scanreg_core::voxel_map::VoxelMap`: the odometry's local map, updated in place.
//!
//! Frozen pyclass around an `RwLock`: registrations read it with the GIL released while no
//! update can interleave; updates take the write lock. Safe to share between Python threads.

use crate::convert::{c_slice, core_err, points_dim, vector};
use numpy::{
    IntoPyArray, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use scanreg_core::icp::NeighborSearch;
use scanreg_core::voxel_map::{Attributes, VoxelMap};
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

type Points = Py<PyArray2<f64>>;
type Distances = Py<numpy::PyArray1<f64>>;

#[pyclass(frozen, module = "scanreg._core")]
pub struct LocalMap {
    inner: RwLock<VoxelMap>,
    dim: usize,
}

impl LocalMap {
    pub fn read(&self) -> RwLockReadGuard<'_, VoxelMap> {
        self.inner.read().unwrap_or_else(|e| e.into_inner())
    }

    fn write(&self) -> RwLockWriteGuard<'_, VoxelMap> {
        self.inner.write().unwrap_or_else(|e| e.into_inner())
    }
}

#[pymethods]
impl LocalMap {
    #[new]
    #[pyo3(signature = (dim, voxel_size, max_points_per_voxel, min_spacing, attributes="none"))]
    fn new(
        dim: usize,
        voxel_size: f64,
        max_points_per_voxel: usize,
        min_spacing: f64,
        attributes: &str,
    ) -> PyResult<Self> {
        let attrs = Attributes::from_name(attributes).map_err(core_err)?;
        let inner = VoxelMap::new(dim, voxel_size, max_points_per_voxel, min_spacing, attrs)
            .map_err(core_err)?;
        Ok(LocalMap {
            inner: RwLock::new(inner),
            dim,
        })
    }

    #[getter]
    fn dim(&self) -> usize {
        self.dim
    }

    #[getter]
    fn voxel_size(&self) -> f64 {
        self.read().voxel_size()
    }

    #[getter]
    fn max_points_per_voxel(&self) -> usize {
        self.read().max_per_voxel()
    }

    #[getter]
    fn attributes(&self) -> &'static str {
        self.read().attributes().name()
    }

    #[getter]
    fn num_voxels(&self) -> usize {
        self.read().num_voxels()
    }

    fn __len__(&self) -> usize {
        self.read().len()
    }

    /// Add world-frame points (with normals or covariances as the map stores); returns how many
    /// were kept.
    #[pyo3(signature = (points, normals=None, covariances=None))]
    fn insert(
        &self,
        py: Python<'_>,
        points: PyReadonlyArray2<'_, f64>,
        normals: Option<PyReadonlyArray2<'_, f64>>,
        covariances: Option<PyReadonlyArray3<'_, f64>>,
    ) -> PyResult<usize> {
        let dim = self.dim;
        let p = points_dim(&points, "points", dim)?;
        let n = p.len() / dim;
        let nrm = match &normals {
            Some(a) => {
                let s = points_dim(a, "normals", dim)?;
                if s.len() != p.len() {
                    return Err(PyValueError::new_err(format!(
                        "normals: expected {n} rows (one per point), got {}",
                        s.len() / dim
                    )));
                }
                Some(s)
            }
            None => None,
        };
        let cov = match &covariances {
            Some(a) => {
                if a.shape() != [n, dim, dim] {
                    return Err(PyValueError::new_err(format!(
                        "covariances: expected shape ({n}, {dim}, {dim}), got {:?}",
                        a.shape()
                    )));
                }
                Some(c_slice(a, "covariances")?)
            }
            None => None,
        };
        py.detach(|| self.write().insert(p, nrm, cov))
            .map_err(core_err)
    }

    /// Drop the voxels farther than `max_distance` from `center`; returns the points removed.
    fn remove_far(&self, center: PyReadonlyArray1<'_, f64>, max_distance: f64) -> PyResult<usize> {
        let c = vector(&center, "center")?;
        self.write().remove_far(c, max_distance).map_err(core_err)
    }

    /// The map's points, `(N, dim)`, in a deterministic order.
    fn points(&self, py: Python<'_>) -> PyResult<Py<PyArray2<f64>>> {
        let c = py.detach(|| self.read().contents());
        let n = c.points.len() / self.dim;
        Ok(c.points.into_pyarray(py).reshape([n, self.dim])?.unbind())
    }

    /// The normals in the order of `points()`, or `None` when the map stores none.
    fn normals(&self, py: Python<'_>) -> PyResult<Option<Py<PyArray2<f64>>>> {
        let c = py.detach(|| self.read().contents());
        if c.normals.is_empty() && self.read().attributes() != Attributes::Normals {
            return Ok(None);
        }
        let n = c.normals.len() / self.dim;
        Ok(Some(
            c.normals.into_pyarray(py).reshape([n, self.dim])?.unbind(),
        ))
    }

    /// The covariances in the order of `points()`, or `None` when the map stores none.
    fn covariances(&self, py: Python<'_>) -> PyResult<Option<Py<PyArray3<f64>>>> {
        let c = py.detach(|| self.read().contents());
        if !matches!(
            self.read().attributes(),
            Attributes::Covariances | Attributes::VoxelCovariances
        ) {
            return Ok(None);
        }
        let d = self.dim;
        let n = c.covariances.len() / (d * d);
        Ok(Some(
            c.covariances.into_pyarray(py).reshape([n, d, d])?.unbind(),
        ))
    }

    /// The rows the registration core reads for the given point ids (the ids of
    /// `register_icp`'s correspondences): `(points, normals, covariances)`.
    #[allow(clippy::type_complexity)]
    fn gather(
        &self,
        py: Python<'_>,
        ids: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<(Points, Option<Points>, Option<Py<PyArray3<f64>>>)> {
        let ids = c_slice(&ids, "ids")?;
        let map = self.read();
        let d = self.dim;
        let cap = map.id_count();
        if let Some(&bad) = ids.iter().find(|&&j| j < 0 || j as usize >= cap) {
            return Err(PyValueError::new_err(format!(
                "ids: {bad} is not a point id of this map (0..{cap})"
            )));
        }
        let rows = |data: &[f64], per: usize| -> Vec<f64> {
            let mut out = Vec::with_capacity(ids.len() * per);
            for &j in ids {
                let j = j as usize;
                out.extend_from_slice(&data[j * per..(j + 1) * per]);
            }
            out
        };
        let pts = rows(NeighborSearch::points(&*map), d);
        let normals = map.normals().map(|v| rows(v, d));
        let group = map.covariance_group();
        let covs = map.covariances().map(|v| {
            let d2 = d * d;
            let mut out = Vec::with_capacity(ids.len() * d2);
            for &j in ids {
                let r = j as usize / group;
                out.extend_from_slice(&v[r * d2..(r + 1) * d2]);
            }
            out
        });
        drop(map);
        let n = ids.len();
        let normals = match normals {
            Some(v) => Some(v.into_pyarray(py).reshape([n, d])?.unbind()),
            None => None,
        };
        let covs = match covs {
            Some(v) => Some(v.into_pyarray(py).reshape([n, d, d])?.unbind()),
            None => None,
        };
        Ok((
            pts.into_pyarray(py).reshape([n, d])?.unbind(),
            normals,
            covs,
        ))
    }

    /// Nearest map point within `max_distance` of each query: `(found, squared distance)`
    /// with the point itself (rows of NaN where none).
    fn nearest(
        &self,
        py: Python<'_>,
        query_points: PyReadonlyArray2<'_, f64>,
        max_distance: f64,
    ) -> PyResult<(Points, Distances)> {
        let dim = self.dim;
        let q = points_dim(&query_points, "query_points", dim)?;
        if !max_distance.is_finite() || max_distance < 0.0 {
            return Err(PyValueError::new_err(format!(
                "max_distance: must be finite and >= 0, got {max_distance}"
            )));
        }
        let (pts, d2) = py
            .detach(|| {
                let map = self.read();
                map.nearest_batch(q, max_distance).map(|(ids, d2)| {
                    let all = NeighborSearch::points(&*map);
                    let mut pts = Vec::with_capacity(q.len());
                    for &j in &ids {
                        if j < 0 {
                            pts.extend(std::iter::repeat_n(f64::NAN, dim));
                        } else {
                            let j = j as usize;
                            pts.extend_from_slice(&all[j * dim..(j + 1) * dim]);
                        }
                    }
                    (pts, d2)
                })
            })
            .map_err(core_err)?;
        let n = d2.len();
        Ok((
            pts.into_pyarray(py).reshape([n, dim])?.unbind(),
            d2.into_pyarray(py).unbind(),
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<LocalMap>()?;
    Ok(())
}

//! Reading a URDF back as a consumer does: its joints, their origins and
//! axes, for forward kinematics written independently of egcal's model.

use nalgebra::{Matrix3, Matrix4, Vector3};

pub fn rx(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}
pub fn ry(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}
pub fn rz(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// A 4×4 homogeneous transform from a URDF `xyz` (m) and `rpy` (rad).
pub fn urdf_transform(xyz: [f64; 3], rpy: [f64; 3]) -> Matrix4<f64> {
    let r = rz(rpy[2]) * ry(rpy[1]) * rx(rpy[0]);
    let mut t = Matrix4::identity();
    t.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    t.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&Vector3::from(xyz));
    t
}

/// The value of attribute `name` in an XML element's text.
pub fn attribute<'a>(element: &'a str, name: &str) -> &'a str {
    let lead = format!("{name}=\"");
    let start = element
        .find(&lead)
        .unwrap_or_else(|| panic!("{name} in {element}"))
        + lead.len();
    let end = element[start..].find('"').unwrap() + start;
    &element[start..end]
}

fn three(text: &str) -> [f64; 3] {
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    [v[0], v[1], v[2]]
}

/// A URDF joint as read back.
#[derive(Debug, Clone)]
pub struct UrdfJoint {
    pub kind: String,
    pub parent: String,
    pub child: String,
    pub origin: Matrix4<f64>,
    pub axis: Option<[f64; 3]>,
}

/// The URDF's joints in file order.
pub fn urdf_joints(text: &str) -> Vec<UrdfJoint> {
    text.split("<joint ")
        .skip(1)
        .map(|chunk| {
            let element = &chunk[..chunk.find("</joint>").unwrap()];
            let parent = attribute(&element[element.find("<parent").unwrap()..], "link");
            let child = attribute(&element[element.find("<child").unwrap()..], "link");
            let origin = &element[element.find("<origin").unwrap()..];
            let axis = element
                .find("<axis")
                .map(|i| three(attribute(&element[i..], "xyz")));
            UrdfJoint {
                kind: attribute(element, "type").to_string(),
                parent: parent.to_string(),
                child: child.to_string(),
                origin: urdf_transform(
                    three(attribute(origin, "xyz")),
                    three(attribute(origin, "rpy")),
                ),
                axis,
            }
        })
        .collect()
}

/// The joints from link `from` to link `to`, in chain order.
pub fn chain(joints: &[UrdfJoint], from: &str, to: &str) -> Vec<UrdfJoint> {
    let mut link = from.to_string();
    let mut chain = Vec::new();
    while let Some(j) = joints.iter().find(|j| j.parent == link) {
        chain.push(j.clone());
        link = j.child.clone();
    }
    assert_eq!(link, to, "the chain from {from} ends at {link}");
    chain
}

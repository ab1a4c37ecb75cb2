//! A small URDF reader: links, inertials, primitive collision/visual shapes and revolute joints.
//!
//! Written on `roxmltree` rather than a full URDF crate because we need only this subset and want
//! clear errors that name the element at fault. Fixed joints are rejected: our model folds fixed
//! parts (feet, head) into their parent link, which keeps the body count (and the solver cost) low.

use std::path::Path;

use rapier3d::math::{Mat3, Pose, Vec3};

use super::description::{
    Geometry, Inertial, Joint, Link, RobotDescription, Shape, pose_from_xyz_rpy,
};
use crate::error::SimError;

/// Parse a URDF document from a file.
pub fn load_urdf(path: &Path) -> Result<RobotDescription, SimError> {
    let text = std::fs::read_to_string(path).map_err(|source| SimError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_urdf(&text)
}

fn bad(msg: impl Into<String>) -> SimError {
    SimError::Urdf(msg.into())
}

/// Parse a URDF document from a string.
pub fn parse_urdf(text: &str) -> Result<RobotDescription, SimError> {
    let doc = roxmltree::Document::parse(text).map_err(|e| bad(format!("not XML: {e}")))?;
    let robot = doc.root_element();
    if robot.tag_name().name() != "robot" {
        return Err(bad("the root element is not <robot>"));
    }
    let name = robot.attribute("name").unwrap_or("robot").to_string();

    let mut links = Vec::new();
    for node in robot.children().filter(|n| n.has_tag_name("link")) {
        links.push(parse_link(node)?);
    }
    let mut joints = Vec::new();
    for node in robot.children().filter(|n| n.has_tag_name("joint")) {
        joints.push(parse_joint(node, &links)?);
    }
    let roots: Vec<usize> = (0..links.len())
        .filter(|&i| joints.iter().all(|j| j.child != i))
        .collect();
    let root = match roots.as_slice() {
        [r] => *r,
        _ => {
            return Err(bad(format!(
                "expected exactly one root link, found {}",
                roots.len()
            )));
        }
    };
    Ok(RobotDescription {
        name,
        links,
        joints,
        root,
    })
}

fn attr<'a>(node: roxmltree::Node<'a, '_>, name: &str) -> Result<&'a str, SimError> {
    node.attribute(name).ok_or_else(|| {
        bad(format!(
            "<{}> lacks the attribute `{name}`",
            node.tag_name().name()
        ))
    })
}

fn parse_f32(text: &str, what: &str) -> Result<f32, SimError> {
    text.trim()
        .parse::<f32>()
        .map_err(|_| bad(format!("{what}: `{text}` is not a number")))
}

fn parse_vec3(text: &str, what: &str) -> Result<Vec3, SimError> {
    let v: Vec<f32> = text
        .split_whitespace()
        .map(|t| parse_f32(t, what))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] => Ok(Vec3::new(*x, *y, *z)),
        _ => Err(bad(format!("{what}: expected 3 numbers, got `{text}`"))),
    }
}

fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, tag: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children().find(|n| n.has_tag_name(tag))
}

fn parse_origin(node: roxmltree::Node, what: &str) -> Result<Pose, SimError> {
    match child(node, "origin") {
        None => Ok(Pose::IDENTITY),
        Some(o) => {
            let xyz = o
                .attribute("xyz")
                .map_or(Ok(Vec3::ZERO), |t| parse_vec3(t, what))?;
            let rpy = o
                .attribute("rpy")
                .map_or(Ok(Vec3::ZERO), |t| parse_vec3(t, what))?;
            Ok(pose_from_xyz_rpy(xyz, rpy))
        }
    }
}

fn parse_link(node: roxmltree::Node) -> Result<Link, SimError> {
    let name = attr(node, "name")?.to_string();
    let inertial = match child(node, "inertial") {
        Some(i) => parse_inertial(i, &name)?,
        None => Inertial {
            mass: 0.0,
            com: Vec3::ZERO,
            inertia: Mat3::ZERO,
        },
    };
    let collisions = node
        .children()
        .filter(|n| n.has_tag_name("collision"))
        .map(|n| parse_geometry(n, &name))
        .collect::<Result<_, _>>()?;
    let visuals = node
        .children()
        .filter(|n| n.has_tag_name("visual"))
        .map(|n| parse_geometry(n, &name))
        .collect::<Result<_, _>>()?;
    Ok(Link {
        name,
        inertial,
        collisions,
        visuals,
    })
}

fn parse_inertial(node: roxmltree::Node, link: &str) -> Result<Inertial, SimError> {
    let what = format!("link `{link}` inertial");
    let origin = parse_origin(node, &what)?;
    let mass = parse_f32(
        attr(
            child(node, "mass").ok_or_else(|| bad(format!("{what}: no <mass>")))?,
            "value",
        )?,
        &what,
    )?;
    let i = child(node, "inertia").ok_or_else(|| bad(format!("{what}: no <inertia>")))?;
    let g = |k: &str| -> Result<f32, SimError> { parse_f32(attr(i, k)?, &what) };
    let (ixx, ixy, ixz, iyy, iyz, izz) = (
        g("ixx")?,
        g("ixy")?,
        g("ixz")?,
        g("iyy")?,
        g("iyz")?,
        g("izz")?,
    );
    let local = Mat3::from_cols(
        Vec3::new(ixx, ixy, ixz),
        Vec3::new(ixy, iyy, iyz),
        Vec3::new(ixz, iyz, izz),
    );
    // URDF gives the tensor in the inertial frame; express it in the link frame's axes.
    let r = Mat3::from_quat(origin.rotation);
    Ok(Inertial {
        mass,
        com: origin.translation,
        inertia: r * local * r.transpose(),
    })
}

fn parse_geometry(node: roxmltree::Node, link: &str) -> Result<Geometry, SimError> {
    let what = format!("link `{link}` {}", node.tag_name().name());
    let origin = parse_origin(node, &what)?;
    let geom = child(node, "geometry").ok_or_else(|| bad(format!("{what}: no <geometry>")))?;
    let shape_node = geom
        .children()
        .find(|n| n.is_element())
        .ok_or_else(|| bad(format!("{what}: empty <geometry>")))?;
    let shape = match shape_node.tag_name().name() {
        "box" => Shape::Box {
            size: parse_vec3(attr(shape_node, "size")?, &what)?,
        },
        "cylinder" => Shape::Cylinder {
            radius: parse_f32(attr(shape_node, "radius")?, &what)?,
            length: parse_f32(attr(shape_node, "length")?, &what)?,
        },
        "sphere" => Shape::Sphere {
            radius: parse_f32(attr(shape_node, "radius")?, &what)?,
        },
        other => {
            return Err(bad(format!(
                "{what}: unsupported geometry <{other}> (primitives only)"
            )));
        }
    };
    Ok(Geometry {
        name: node.attribute("name").unwrap_or("").to_string(),
        origin,
        shape,
    })
}

fn parse_joint(node: roxmltree::Node, links: &[Link]) -> Result<Joint, SimError> {
    let name = attr(node, "name")?.to_string();
    let what = format!("joint `{name}`");
    let kind = attr(node, "type")?;
    if kind != "revolute" {
        return Err(bad(format!(
            "{what}: type `{kind}` is not supported (revolute only)"
        )));
    }
    let find = |tag: &str| -> Result<usize, SimError> {
        let link = attr(
            child(node, tag).ok_or_else(|| bad(format!("{what}: no <{tag}>")))?,
            "link",
        )?;
        links
            .iter()
            .position(|l| l.name == link)
            .ok_or_else(|| bad(format!("{what}: unknown {tag} link `{link}`")))
    };
    let (parent, child_link) = (find("parent")?, find("child")?);
    let origin = parse_origin(node, &what)?;
    let axis = match child(node, "axis") {
        Some(a) => parse_vec3(attr(a, "xyz")?, &what)?,
        None => Vec3::X,
    };
    if axis.length() < 1e-6 {
        return Err(bad(format!("{what}: zero axis")));
    }
    let limit = child(node, "limit").ok_or_else(|| bad(format!("{what}: no <limit>")))?;
    let lim = |k: &str| -> Result<f32, SimError> { parse_f32(attr(limit, k)?, &what) };
    let (lower, upper) = (lim("lower")?, lim("upper")?);
    if lower >= upper {
        return Err(bad(format!(
            "{what}: lower limit {lower} is not below upper limit {upper}"
        )));
    }
    Ok(Joint {
        name,
        parent,
        child: child_link,
        origin,
        axis: axis.normalize(),
        lower,
        upper,
        effort: lim("effort")?,
        velocity: lim("velocity")?,
    })
}

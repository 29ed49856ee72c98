//! `run --record FILE`: an MCAP file of Foxglove JSON messages, read back with the mcap crate's
//! reader; every message checked against the JSON schema the file embeds for its channel.

use crate::common::{ok_json, stillpoint, synth_walking};
use serde_json::Value;
use std::collections::BTreeMap;

/// Where `value` breaks `schema` (the part of JSON Schema Foxglove's schemas use: type,
/// properties, required, items, oneOf of consts, minimum / maximum, minItems / maxItems), and
/// fields the schema does not define. Empty when it conforms.
fn violations(schema: &Value, value: &Value, at: &str) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(one_of) = schema["oneOf"].as_array() {
        if !one_of.iter().any(|c| c["const"] == *value) {
            out.push(format!("{at}: {value} is none of {one_of:?}"));
        }
        return out;
    }
    let ty = schema["type"].as_str().unwrap_or("");
    let ok = match ty {
        "object" => value.is_object(),
        "array" => value.is_array(),
        "string" => value.is_string(),
        "number" => value.is_number(),
        "integer" => value.is_u64() || value.is_i64(),
        "boolean" => value.is_boolean(),
        "" => true,
        other => panic!("{at}: schema type {other} not handled"),
    };
    if !ok {
        out.push(format!("{at}: {value} is not {ty}"));
        return out;
    }
    if let (Some(min), Some(v)) = (schema["minimum"].as_f64(), value.as_f64())
        && v < min
    {
        out.push(format!("{at}: {v} < {min}"));
    }
    if let (Some(max), Some(v)) = (schema["maximum"].as_f64(), value.as_f64())
        && v > max
    {
        out.push(format!("{at}: {v} > {max}"));
    }
    if schema["contentEncoding"] == "base64" {
        let s = value.as_str().unwrap();
        if !s.len().is_multiple_of(4)
            || !s
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"+/=".contains(&b))
        {
            out.push(format!("{at}: not base64"));
        }
    }
    if let Some(items) = value.as_array() {
        let n = items.len() as u64;
        if schema["minItems"].as_u64().is_some_and(|m| n < m)
            || schema["maxItems"].as_u64().is_some_and(|m| n > m)
        {
            out.push(format!("{at}: {n} items"));
        }
        for (i, item) in items.iter().enumerate() {
            out.extend(violations(&schema["items"], item, &format!("{at}[{i}]")));
        }
    }
    if let Some(fields) = value.as_object() {
        let props = schema["properties"].as_object().unwrap();
        for req in schema["required"].as_array().into_iter().flatten() {
            if !fields.contains_key(req.as_str().unwrap()) {
                out.push(format!("{at}: missing {req}"));
            }
        }
        for (k, v) in fields {
            match props.get(k) {
                Some(s) => out.extend(violations(s, v, &format!("{at}.{k}"))),
                None => out.push(format!("{at}: {k} is not in the schema")),
            }
        }
    }
    out
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let mut out = Vec::new();
    for chunk in s.as_bytes().chunks(4) {
        let pad = chunk.iter().filter(|&&c| c == b'=').count();
        let n = chunk.iter().fold(0u32, |n, &c| {
            (n << 6) | u32::from(if c == b'=' { 0 } else { val(c) })
        });
        out.extend_from_slice(&n.to_be_bytes()[1..4 - pad]);
    }
    out
}

#[test]
fn the_recording_opens_with_the_reference_reader_and_every_message_fits_its_schema() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_walking(&seq, 12, &[]);
    let file = tmp.path().join("run.mcap");
    let out = stillpoint()
        .args([
            "run",
            "--detector",
            "gt",
            "--sequential",
            "--json",
            "--dataset",
        ])
        .arg(&seq)
        .arg("--out")
        .arg(tmp.path().join("traj.txt"))
        .arg("--record")
        .arg(&file)
        .output()
        .unwrap();
    let summary = ok_json(&out);
    let (frames, tracked) = (
        summary["frames"].as_u64().unwrap() as usize,
        summary["tracked"].as_u64().unwrap() as usize,
    );
    assert!(tracked >= 10, "{summary}");

    let bytes = std::fs::read(&file).unwrap();
    // Finished: the summary section lists the schemas and channels.
    let index = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let topics: BTreeMap<String, (String, String, String)> = index
        .channels
        .values()
        .map(|c| {
            let s = c.schema.as_ref().unwrap();
            (
                c.topic.clone(),
                (
                    s.name.clone(),
                    s.encoding.clone(),
                    c.message_encoding.clone(),
                ),
            )
        })
        .collect();
    for (topic, schema) in stillpoint_run::record::TOPICS {
        assert_eq!(
            topics[topic],
            (schema.into(), "jsonschema".into(), "json".into())
        );
    }

    let mut by_topic: BTreeMap<String, Vec<(u64, Value)>> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        let schema: Value = serde_json::from_slice(&schema.data).unwrap();
        let v: Value = serde_json::from_slice(&m.data).unwrap();
        let bad = violations(&schema, &v, &m.channel.topic);
        assert!(bad.is_empty(), "{bad:?}");
        by_topic
            .entry(m.channel.topic.clone())
            .or_default()
            .push((m.log_time, v));
    }
    let count = |t: &str| by_topic.get(t).map_or(0, Vec::len);
    assert_eq!(count("/camera/image"), frames);
    assert_eq!(count("/camera/calibration"), frames);
    assert_eq!(count("/camera/annotations"), frames);
    assert_eq!(count("/tf"), tracked);
    assert_eq!(count("/points/moving"), tracked);
    assert!(count("/map/points") >= 2 && count("/map/keyframes") == count("/map/points"));
    let recorded: BTreeMap<String, usize> =
        by_topic.iter().map(|(t, v)| (t.clone(), v.len())).collect();
    assert_eq!(summary["record"]["messages"], serde_json::json!(recorded));
    assert_eq!(summary["record"]["bytes"], bytes.len());

    // Log times are the frames' stamps, in order.
    let traj = stillpoint_trajectory::read_tum(&tmp.path().join("traj.txt")).unwrap();
    let images = &by_topic["/camera/image"];
    assert!(images.windows(2).all(|w| w[0].0 < w[1].0));
    let first = images[0].0 as f64 * 1e-9;
    assert!(
        (first - traj.stamps[0]).abs() < 1e-5,
        "{first} {}",
        traj.stamps[0]
    );
    // The image is a JPEG of the frame's size.
    let jpeg = base64_decode(images[0].1["data"].as_str().unwrap());
    let jpeg_file = tmp.path().join("f.jpg");
    std::fs::write(&jpeg_file, jpeg).unwrap();
    let img = stillpoint_image::read_rgb(&jpeg_file).unwrap();
    let calib = &by_topic["/camera/calibration"][0].1;
    assert_eq!(
        (img.width as u64, img.height as u64),
        (
            calib["width"].as_u64().unwrap(),
            calib["height"].as_u64().unwrap()
        )
    );
    // The walkers: culled keypoints (red) and boxes judged moving (red line loops) on the last
    // frame; static keypoints matched (green).
    let last = &by_topic["/camera/annotations"].last().unwrap().1;
    let red = serde_json::json!({"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0});
    let points = last["points"].as_array().unwrap();
    let culled = points
        .iter()
        .find(|p| p["type"] == 1 && p["outline_color"] == red)
        .unwrap();
    assert!(culled["points"].as_array().unwrap().len() > 20, "{culled}");
    assert!(
        points
            .iter()
            .any(|p| p["type"] == 2 && p["outline_color"] == red)
    );
    assert!(
        last["texts"]
            .as_array()
            .unwrap()
            .iter()
            .any(|t| t["text"] == "person moving")
    );
    // The culled keypoints with depth, in 3D.
    let moving = &by_topic["/points/moving"].last().unwrap().1;
    let n_moving = base64_decode(moving["data"].as_str().unwrap()).len() / 16;
    assert!(n_moving > 10, "{n_moving}");
    // At the end: the final map (as many points as the run reports) and trajectory.
    let map = &by_topic["/map/points"].last().unwrap().1;
    let n_map = base64_decode(map["data"].as_str().unwrap()).len() / 16;
    assert_eq!(n_map as u64, summary["map_points"].as_u64().unwrap());
    let path = &by_topic["/camera/path"].last().unwrap().1;
    assert_eq!(path["poses"].as_array().unwrap().len(), traj.len());
    let last_pose = &path["poses"][traj.len() - 1]["position"];
    let t = traj.poses[traj.len() - 1].translation.vector;
    assert!((last_pose["x"].as_f64().unwrap() - t.x).abs() < 1e-9);
}

#[test]
fn an_unwritable_recording_is_one_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    crate::common::synth_static(&seq, 3, 0);
    let bad = tmp.path().join("no-such-dir").join("run.mcap");
    let out = stillpoint()
        .args(["run", "--detector", "none", "--sequential", "--dataset"])
        .arg(&seq)
        .arg("--out")
        .arg(tmp.path().join("traj.txt"))
        .arg("--record")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no-such-dir/run.mcap"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

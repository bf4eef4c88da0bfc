//! The part of Embree 3.13's C API (`/usr/include/embree3/*.h`) that the peers call: devices,
//! `rtcBuildBVH` with its callbacks (rtcore_builder.h), and a triangle scene traced with
//! `rtcIntersect1` (rtcore_scene.h). Declared here rather than through the `embree3` crate, which
//! links the library unconditionally: bvhlab must still build where Embree is not installed.
//! Layouts follow the headers of 3.13.5 with `RTC_MAX_INSTANCE_LEVEL_COUNT = 1` and
//! `RTC_MIN_WIDTH = 0` (Debian's build); the size asserts below guard them.
#![allow(non_camel_case_types, non_snake_case, dead_code)]
use std::ffi::{c_char, c_void};

pub type RTCDevice = *mut c_void;
pub type RTCScene = *mut c_void;
pub type RTCGeometry = *mut c_void;
pub type RTCBVH = *mut c_void;
pub type RTCThreadLocalAllocator = *mut c_void;

pub const RTC_BUILD_QUALITY_LOW: u32 = 0;
pub const RTC_BUILD_QUALITY_MEDIUM: u32 = 1;
pub const RTC_BUILD_QUALITY_HIGH: u32 = 2;
pub const RTC_DEVICE_PROPERTY_VERSION: u32 = 0;
pub const RTC_GEOMETRY_TYPE_TRIANGLE: u32 = 0;
pub const RTC_BUFFER_TYPE_INDEX: u32 = 0;
pub const RTC_BUFFER_TYPE_VERTEX: u32 = 1;
pub const RTC_FORMAT_UINT3: u32 = 0x5003;
pub const RTC_FORMAT_FLOAT3: u32 = 0x9003;
pub const RTC_INVALID_GEOMETRY_ID: u32 = u32::MAX;
/// rtcore_builder.h: `RTC_BUILD_MAX_PRIMITIVES_PER_LEAF`.
pub const RTC_BUILD_MAX_PRIMITIVES_PER_LEAF: u32 = 32;

#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, Default)]
pub struct RTCBuildPrimitive {
    pub lower_x: f32,
    pub lower_y: f32,
    pub lower_z: f32,
    pub geomID: u32,
    pub upper_x: f32,
    pub upper_y: f32,
    pub upper_z: f32,
    pub primID: u32,
}

#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
pub struct RTCBounds {
    pub lower_x: f32,
    pub lower_y: f32,
    pub lower_z: f32,
    pub align0: f32,
    pub upper_x: f32,
    pub upper_y: f32,
    pub upper_z: f32,
    pub align1: f32,
}

pub type RTCCreateNodeFunction =
    unsafe extern "C" fn(RTCThreadLocalAllocator, u32, *mut c_void) -> *mut c_void;
pub type RTCSetNodeChildrenFunction =
    unsafe extern "C" fn(*mut c_void, *mut *mut c_void, u32, *mut c_void);
pub type RTCSetNodeBoundsFunction =
    unsafe extern "C" fn(*mut c_void, *mut *const RTCBounds, u32, *mut c_void);
pub type RTCCreateLeafFunction = unsafe extern "C" fn(
    RTCThreadLocalAllocator,
    *const RTCBuildPrimitive,
    usize,
    *mut c_void,
) -> *mut c_void;
pub type RTCSplitPrimitiveFunction = unsafe extern "C" fn(
    *const RTCBuildPrimitive,
    u32,
    f32,
    *mut RTCBounds,
    *mut RTCBounds,
    *mut c_void,
);
pub type RTCProgressMonitorFunction = unsafe extern "C" fn(*mut c_void, f64) -> bool;

#[repr(C)]
pub struct RTCBuildArguments {
    pub byteSize: usize,
    pub buildQuality: u32,
    pub buildFlags: u32,
    pub maxBranchingFactor: u32,
    pub maxDepth: u32,
    pub sahBlockSize: u32,
    pub minLeafSize: u32,
    pub maxLeafSize: u32,
    pub traversalCost: f32,
    pub intersectionCost: f32,
    pub bvh: RTCBVH,
    pub primitives: *mut RTCBuildPrimitive,
    pub primitiveCount: usize,
    pub primitiveArrayCapacity: usize,
    pub createNode: Option<RTCCreateNodeFunction>,
    pub setNodeChildren: Option<RTCSetNodeChildrenFunction>,
    pub setNodeBounds: Option<RTCSetNodeBoundsFunction>,
    pub createLeaf: Option<RTCCreateLeafFunction>,
    pub splitPrimitive: Option<RTCSplitPrimitiveFunction>,
    pub buildProgress: Option<RTCProgressMonitorFunction>,
    pub userPtr: *mut c_void,
}

impl RTCBuildArguments {
    /// `rtcDefaultBuildArguments()` (an inline function in the header, so not in the library).
    pub fn default_args() -> RTCBuildArguments {
        RTCBuildArguments {
            byteSize: std::mem::size_of::<RTCBuildArguments>(),
            buildQuality: RTC_BUILD_QUALITY_MEDIUM,
            buildFlags: 0,
            maxBranchingFactor: 2,
            maxDepth: 32,
            sahBlockSize: 1,
            minLeafSize: 1,
            maxLeafSize: RTC_BUILD_MAX_PRIMITIVES_PER_LEAF,
            traversalCost: 1.0,
            intersectionCost: 1.0,
            bvh: std::ptr::null_mut(),
            primitives: std::ptr::null_mut(),
            primitiveCount: 0,
            primitiveArrayCapacity: 0,
            createNode: None,
            setNodeChildren: None,
            setNodeBounds: None,
            createLeaf: None,
            splitPrimitive: None,
            buildProgress: None,
            userPtr: std::ptr::null_mut(),
        }
    }
}

#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
pub struct RTCRay {
    pub org_x: f32,
    pub org_y: f32,
    pub org_z: f32,
    pub tnear: f32,
    pub dir_x: f32,
    pub dir_y: f32,
    pub dir_z: f32,
    pub time: f32,
    pub tfar: f32,
    pub mask: u32,
    pub id: u32,
    pub flags: u32,
}

#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
pub struct RTCHit {
    pub Ng_x: f32,
    pub Ng_y: f32,
    pub Ng_z: f32,
    pub u: f32,
    pub v: f32,
    pub primID: u32,
    pub geomID: u32,
    pub instID: [u32; 1],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct RTCRayHit {
    pub ray: RTCRay,
    pub hit: RTCHit,
}

/// `rtcInitIntersectContext` is inline in the header: flags = incoherent, no filter, instID invalid.
#[repr(C)]
pub struct RTCIntersectContext {
    pub flags: u32,
    pub filter: *mut c_void,
    pub instID: [u32; 1],
}

const _: () = assert!(std::mem::size_of::<RTCBuildPrimitive>() == 32);
const _: () = assert!(std::mem::size_of::<RTCBounds>() == 32);
const _: () = assert!(std::mem::size_of::<RTCRay>() == 48);
const _: () = assert!(std::mem::size_of::<RTCHit>() == 32);
const _: () = assert!(std::mem::size_of::<RTCRayHit>() == 80);
const _: () = assert!(std::mem::size_of::<RTCIntersectContext>() == 24);
const _: () = assert!(std::mem::size_of::<RTCBuildArguments>() == 136);

extern "C" {
    pub fn rtcNewDevice(config: *const c_char) -> RTCDevice;
    pub fn rtcReleaseDevice(device: RTCDevice);
    pub fn rtcGetDeviceProperty(device: RTCDevice, prop: u32) -> isize;
    pub fn rtcGetDeviceError(device: RTCDevice) -> u32;
    pub fn rtcNewBVH(device: RTCDevice) -> RTCBVH;
    pub fn rtcBuildBVH(args: *const RTCBuildArguments) -> *mut c_void;
    pub fn rtcThreadLocalAlloc(
        allocator: RTCThreadLocalAllocator,
        bytes: usize,
        align: usize,
    ) -> *mut c_void;
    pub fn rtcReleaseBVH(bvh: RTCBVH);
    pub fn rtcNewScene(device: RTCDevice) -> RTCScene;
    pub fn rtcReleaseScene(scene: RTCScene);
    pub fn rtcSetSceneBuildQuality(scene: RTCScene, quality: u32);
    pub fn rtcNewGeometry(device: RTCDevice, kind: u32) -> RTCGeometry;
    pub fn rtcSetNewGeometryBuffer(
        geometry: RTCGeometry,
        kind: u32,
        slot: u32,
        format: u32,
        byte_stride: usize,
        item_count: usize,
    ) -> *mut c_void;
    pub fn rtcSetGeometryBuildQuality(geometry: RTCGeometry, quality: u32);
    pub fn rtcCommitGeometry(geometry: RTCGeometry);
    pub fn rtcAttachGeometry(scene: RTCScene, geometry: RTCGeometry) -> u32;
    pub fn rtcReleaseGeometry(geometry: RTCGeometry);
    pub fn rtcCommitScene(scene: RTCScene);
    pub fn rtcIntersect1(
        scene: RTCScene,
        context: *mut RTCIntersectContext,
        rayhit: *mut RTCRayHit,
    );
}

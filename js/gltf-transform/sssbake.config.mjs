// `gltf-transform --config js/gltf-transform/sssbake.config.mjs <command> in.glb out.glb` keeps sssbake's
// SSSBAKE_subsurface data: the CLI's own extensions plus this one (a config's list replaces the CLI's).
import { ALL_EXTENSIONS } from '@gltf-transform/extensions';
import { SSSBakeSubsurface } from './sssbake-extension.mjs';

export default { extensions: [...ALL_EXTENSIONS, SSSBakeSubsurface] };

/** URLs of the server this page came from; a `?token=` in the page's address is passed on (off-loopback auth). */
import type { EpisodeListItem, EpisodeRecord } from "../messages";

function token(): string | null {
  return new URLSearchParams(window.location.search).get("token");
}

function withToken(path: string): string {
  const t = token();
  return t ? `${path}${path.includes("?") ? "&" : "?"}token=${encodeURIComponent(t)}` : path;
}

export function wsUrl(): string {
  const proto = window.location.protocol === "https:" ? "wss:" : "ws:";
  return withToken(`${proto}//${window.location.host}/ws`);
}

export function frameUrl(episodeId: string, t: number): string {
  return withToken(`/api/episodes/${encodeURIComponent(episodeId)}/frames/${t}`);
}

async function getJson<T>(path: string): Promise<T> {
  const res = await fetch(withToken(path));
  if (!res.ok) throw new Error(`${path}: ${res.status} ${await res.text()}`);
  return (await res.json()) as T;
}

export const fetchEpisodes = (): Promise<EpisodeListItem[]> => getJson<EpisodeListItem[]>("/api/episodes");

export const fetchEpisode = (id: string): Promise<EpisodeRecord> =>
  getJson<EpisodeRecord>(`/api/episodes/${encodeURIComponent(id)}`);
